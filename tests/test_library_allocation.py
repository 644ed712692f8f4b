"""Library allocation (issue 48, 2: one λ for the library): the equal-slope choice of each material's record among
its rungs under the library's total, the ladder of budgets, and ``--allocate library`` keeping a file within N bytes
per material, its header included."""

from __future__ import annotations

import itertools
import subprocess
import sys

import numpy as np
import pytest

from brdfcodec.codec.allocation import allocate_bytes, budget_ladder
from brdfcodec.errors import RateTargetError


def _brute_force(choices: list[list[tuple[int, float]]], total: int) -> float:
    best = np.inf
    for pick in itertools.product(*(range(len(c)) for c in choices)):
        if sum(choices[i][j][0] for i, j in enumerate(pick)) <= total:
            best = min(best, sum(choices[i][j][1] for i, j in enumerate(pick)))
    return float(best)


def _convex_choices(rng: np.random.Generator, items: int) -> list[list[tuple[int, float]]]:
    """Per item, rising sizes and strictly falling distortions with shrinking gains per byte (a convex
    rate–distortion curve)."""
    out = []
    for _ in range(items):
        sizes = np.cumsum(rng.integers(1, 5, size=int(rng.integers(2, 6)))) + 8
        gains = np.sort(rng.uniform(0.01, 0.5, size=len(sizes) - 1))[::-1]  # each byte saves less than the last
        drops = np.concatenate([[0.0], np.cumsum(gains * np.diff(sizes))])
        distortion = drops[-1] + rng.uniform(0.1, 0.5) - drops
        out.append([(int(s), float(d)) for s, d in zip(sizes, distortion, strict=True)])
    return out


@pytest.mark.parametrize("seed", range(6))
def test_the_choice_fits_the_total_and_is_optimal_on_convex_curves_at_their_vertices(seed: int) -> None:
    rng = np.random.default_rng(seed)
    choices = _convex_choices(rng, 4)
    smallest = sum(c[0][0] for c in choices)
    largest = sum(c[-1][0] for c in choices)
    largest_step = max(a[1] - b[1] for c in choices for a, b in itertools.pairwise(c))
    exact = 0
    for total in range(smallest, largest + 1):
        picks = allocate_bytes(choices, total)
        used = sum(choices[i][j][0] for i, j in enumerate(picks))
        assert used <= total
        summed = sum(choices[i][j][1] for i, j in enumerate(picks))
        optimum = _brute_force(choices, total)
        # the greedy over hull steps is the Lagrangian solution: optimal where the total falls on a vertex, and
        # never worse than the optimum by more than one step's saving (the step that did not fit)
        assert summed <= optimum + largest_step + 1e-12
        exact += summed <= optimum + 1e-12
    assert exact >= (largest - smallest + 1) // 3  # optimal at a good share of the totals, not only bounded
    # the whole budget: everyone's largest; the smallest budget: everyone's smallest
    assert allocate_bytes(choices, largest) == [len(c) - 1 for c in choices]
    assert allocate_bytes(choices, smallest) == [0] * len(choices)


def test_bytes_go_where_they_save_the_most() -> None:
    # two materials: a byte on the first saves 0.01 each, on the second 0.1 each
    flat = [(10, 0.50), (14, 0.46), (18, 0.42)]
    steep = [(10, 0.90), (14, 0.50), (18, 0.30)]
    assert allocate_bytes([flat, steep], 24) == [0, 1]
    assert allocate_bytes([flat, steep], 28) == [0, 2]
    assert allocate_bytes([flat, steep], 32) == [1, 2]
    # the same total spread evenly would err more
    even = flat[1][1] + steep[1][1]
    chosen = allocate_bytes([flat, steep], 28)
    assert flat[chosen[0]][1] + steep[chosen[1]][1] < even


def test_a_point_above_the_hull_still_takes_bytes_left_over() -> None:
    # (12, 0.8) lies above the chord from (10, 0.9) to (20, 0.5): no hull step reaches it, but with 12 bytes it
    # is the best that fits
    assert allocate_bytes([[(10, 0.9), (12, 0.8), (20, 0.5)]], 12) == [1]
    assert allocate_bytes([[(10, 0.9), (12, 0.8), (20, 0.5)]], 19) == [1]
    assert allocate_bytes([[(10, 0.9), (12, 0.8), (20, 0.5)]], 20) == [2]


def test_too_small_a_total_is_refused_naming_both_sizes() -> None:
    with pytest.raises(RateTargetError, match="30 bytes together, above the 29"):
        allocate_bytes([[(10, 1.0)], [(20, 1.0), (25, 0.5)]], 29)
    with pytest.raises(ValueError, match="item 1 has no candidate"):
        allocate_bytes([[(10, 1.0)], []], 100)
    with pytest.raises(ValueError, match="not finite"):
        allocate_bytes([[(10, float("nan"))]], 100)


def test_the_ladder_spans_the_mean_and_respects_the_floor() -> None:
    assert budget_ladder(16) == (10, 12, 14, 16, 18, 20, 24, 32)
    assert budget_ladder(16, smallest=13) == (13, 14, 16, 18, 20, 24, 32)
    assert 64 in budget_ladder(64) and max(budget_ladder(64)) == 128
    with pytest.raises(ValueError):
        budget_ladder(0)


@pytest.mark.slow
def test_library_allocation_fits_the_file_and_errs_no_more_than_even_records(tmp_path, analytic_tables) -> None:
    """Three analytic presets on the shipped model through ``bvae compress --bytes 40 --allocate library``: the file
    within 40 bytes a material besides the names, its header included, records of different sizes, and a mean
    full-table error no higher than that of the largest even ``--bytes`` whose file fits the same size."""
    import brdfcodec as bc
    from brdfcodec.cli.main import main
    from brdfcodec.format.reader import parse_bvae
    from brdfcodec.io.merl import write_merl
    from brdfcodec.representation.metrics import relae_both

    materials = [analytic_tables[name] for name in ("gold", "red-plastic", "white-matte")]
    paths = []
    for material in materials:
        paths.append(tmp_path / f"{material.name}.binary")
        write_merl(paths[-1], material)
    names = sum(len(m.name.encode("utf-8")) for m in materials)
    mean, count = 40, len(materials)

    def error(data: bytes) -> float:
        library = bc.decode(data)
        return float(np.mean([relae_both(m.values, library[m.name].table(), m.mask)[1].overall for m in materials]))

    out = tmp_path / "library.bvae"
    assert main(["compress", *map(str, paths), "-o", str(out), "--bytes", str(mean), "--allocate", "library",
                 "--no-measure"]) == 0
    allocated = out.read_bytes()
    assert len(allocated) - names <= mean * count
    header = parse_bvae(allocated).header
    records = [entry.length + entry.descriptor_bytes for entry in header.entries]
    assert len(set(records)) > 1  # the bytes went where they lower the error, not evenly
    # the largest even --bytes whose file fits, searched from the allocated file's header share
    flag = mean - -(-(len(allocated) - names - sum(records)) // count)
    fits = {}
    while flag not in fits:
        data = bc.encode(materials, bytes=flag, measure_error=False)
        fits[flag] = data if len(data) - names <= mean * count else None
        flag = flag + 1 if fits[flag] is not None else flag - 1
    even = fits[max(f for f, d in fits.items() if d is not None)]
    assert error(allocated) <= error(even) * 1.01


def test_the_cli_refuses_allocate_without_bytes(tmp_path) -> None:
    result = subprocess.run([sys.executable, "-m", "brdfcodec", "compress", "x.binary", "-o",
                             str(tmp_path / "out.bvae"), "--allocate", "library"], capture_output=True, text=True)
    assert result.returncode == 2
    assert "--allocate spreads a size budget: give --bytes" in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "out.bvae").exists()


def test_a_library_too_small_for_its_header_is_refused_before_encoding(tmp_path, red_plastic_file) -> None:
    out = tmp_path / "out.bvae"
    result = subprocess.run([sys.executable, "-m", "brdfcodec", "compress", str(red_plastic_file), "-o", str(out),
                             "--bytes", "30", "--allocate", "library"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 1
    assert "1 material cannot fit 30 bytes each: the file's header takes at least 40 bytes" in result.stderr
    assert "Traceback" not in result.stderr and not out.exists()


def _ladders() -> tuple[list[list], object]:
    """Four materials, two groups; each material's rungs: μ alone (a small record, one form) and μ with σ (a larger
    one, another form), the first material of each group gaining much from the larger one, the second little."""
    from brdfcodec.codec.encoding import Rung
    from brdfcodec.format.bvae import DecoderReference, LatentRecord, record_size
    from brdfcodec.format.layered_record import LayeredRecord

    def rung(name: str, full: bool, distortion: float) -> Rung:
        record = LatentRecord(name, np.linspace(-1, 1, 8, dtype=np.float32), np.ones(8, dtype=np.float32))
        record = record if full else LayeredRecord.code_only(record)
        return Rung(record, record_size(record, "float32"), distortion)

    gains = {"a0": 0.2, "a1": 0.95, "b0": 0.3, "b1": 0.9}
    ladders = [[rung(name, False, 1.0), rung(name, True, low)] for name, low in gains.items()]
    return ladders, DecoderReference("ab" * 32, "test")


def test_the_chosen_file_fits_every_group_and_upgrades_the_steep_material_first() -> None:
    from brdfcodec.codec.library_budget import choose_rungs
    from brdfcodec.format.bvae import encode_bvae

    ladders, reference = _ladders()
    groups = ["a", "a", "b", "b"]
    names = sum(len(r[0].record.name) for r in ladders)
    small, large = ladders[0][0].record_bytes, ladders[0][1].record_bytes
    floor = None
    for mean in range(small, 2 * large + 60):
        try:
            records = choose_rungs(ladders, mean, reference, groups=groups)
        except RateTargetError:
            assert floor is None  # once a mean fits, every larger one does
            continue
        floor = mean if floor is None else floor
        data = encode_bvae(records, reference, short_references=True)
        sizes = [record_bytes for record_bytes in (
            large if getattr(r, "store_sigma", True) else small for r in records)]
        header = (len(data) - names - sum(sizes)) / len(records)
        for indices in ([0, 1], [2, 3]):  # each group within its share, its header share included
            assert sum(sizes[i] for i in indices) + len(indices) * header <= len(indices) * mean
        upgraded = [size == large for size in sizes]
        assert upgraded[1] <= upgraded[0] and upgraded[3] <= upgraded[2]  # the steep one first
    assert floor is not None
    # the smallest mean that holds the smallest records' file is accepted: the header of a larger choice's file
    # (another form) is not held against it
    smallest = encode_bvae([r[0].record for r in ladders], reference, short_references=True)
    assert floor == -(-(len(smallest) - names) // len(ladders))


def test_groups_of_the_wrong_length_are_refused_before_encoding() -> None:
    import brdfcodec as bc

    with pytest.raises(ValueError, match="groups gives 1 labels for 2 materials"):
        bc.encode(["a.binary", "b.binary"], bytes=64, allocate="library", groups=["x"])


def _two_form_ladders(count: int) -> list[list]:
    """``count`` materials whose larger rung costs 2 bytes more in a record but another form: μ on the fixed
    grid (8 bytes) or with its own step (10 bytes), no σ. A file mixing the two forms spends more on its header
    than the upgrade costs in records."""
    from brdfcodec.codec.encoding import Rung
    from brdfcodec.format.bvae import record_size
    from brdfcodec.format.layered_record import LayeredRecord

    def rung(name: str, fixed: bool, distortion: float) -> Rung:
        record = LayeredRecord(name, np.linspace(-1, 1, 8, dtype=np.float32), np.ones(8, dtype=np.float32), {},
                               store_sigma=False, compact_mu=True, fixed_mu_grid=fixed)
        return Rung(record, record_size(record, "float32"), distortion)

    return [[rung(f"m{i}", True, 1.0), rung(f"m{i}", False, 0.5)] for i in range(count)]


@pytest.mark.parametrize("count", [2, 3, 4])
def test_where_no_larger_choice_fits_beside_its_header_the_smallest_records_are_kept(count: int) -> None:
    from brdfcodec.codec.library_budget import choose_rungs
    from brdfcodec.format.bvae import DecoderReference, encode_bvae

    reference = DecoderReference("ab" * 32, "test")
    ladders = _two_form_ladders(count)
    names = sum(len(rungs[0].record.name) for rungs in ladders)
    smallest = len(encode_bvae([rungs[0].record for rungs in ladders], reference, short_references=True)) - names
    largest = len(encode_bvae([rungs[1].record for rungs in ladders], reference, short_references=True)) - names
    kept_smallest = 0
    for mean in range(-(-smallest // count), -(-largest // count) + 2):  # every mean whose smallest file fits
        records = choose_rungs(ladders, mean, reference)
        size = len(encode_bvae(records, reference, short_references=True)) - names
        assert size <= count * mean
        kept_smallest += all(record.fixed_mu_grid for record in records)
    # at the smallest file's mean an upgrade's file (two forms) is larger than its record bytes suggest: only the
    # smallest records fit there
    assert kept_smallest >= 1
