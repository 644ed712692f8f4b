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
