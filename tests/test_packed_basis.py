"""Packed basis layers (format 2.3, ``spec/bvae-format.md`` §4.7): widths, bytes, choice, files and rate control."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.format.bvae import DecoderReference, encode_bvae, parse_bvae
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.layers.basis import BasisLayer, packed_coefficients, quantise_coefficients
from brdfcodec.layers.packed import (
    choose_packing,
    pack_fields,
    packed_bytes,
    packed_step,
    packed_step_code,
    packed_widths,
    unpack_fields,
)

SHA = "cd" * 32
DECODER = DecoderReference("ab" * 32, "test")


def test_widths_follow_the_worked_example_of_the_spec() -> None:
    assert packed_widths(9, 0, 4).tolist() == [9, 8, 7, 7]
    assert packed_widths(9, 8, 4).tolist() == [6, 6, 6, 5]
    # round(log2 n) exactly at the boundaries: log2(n) crosses k + 0.5 between n = 2^k·√2 and the next integer
    n = np.arange(1, 5000)
    assert (9 - packed_widths(9, 0, len(n)) == np.floor(np.log2(n) + 0.5)).all()
    assert packed_bytes(9, 0, 4) == 1 + 4  # 31 bits in 4 bytes after the step code


def test_fields_round_trip_at_their_extremes_and_refuse_what_does_not_fit() -> None:
    rng = np.random.default_rng(0)
    widths = rng.integers(1, 20, size=200)
    values = np.array([rng.integers(-(1 << (b - 1)), 1 << (b - 1)) for b in widths])
    values[:3] = [-(1 << (widths[0] - 1)), (1 << (widths[1] - 1)) - 1, 0]
    data = pack_fields(values, widths)
    assert len(data) == (widths.sum() + 7) // 8
    assert unpack_fields(data, widths).tolist() == values.tolist()
    assert pack_fields([3, -3, 0], [9, 8, 7]) == bytes([3, 250, 1])  # least significant bit first
    with pytest.raises(ValueError, match="does not fit"):
        pack_fields([1 << 4], [5])
    with pytest.raises(ValueError, match="unused bits"):
        unpack_fields(bytes([3, 125, 128]), [8, 7, 6])
    with pytest.raises(ValueError, match="take 3 bytes"):
        unpack_fields(bytes([3, 125]), [8, 7, 6])


def test_step_codes_are_a_grid_of_sixteen_per_octave() -> None:
    assert packed_step(128) == 1.0 and packed_step(144) == 2.0 and packed_step(0) == 2.0 ** -8
    for code in (0, 1, 77, 128, 255):
        assert packed_step_code(packed_step(code)) == code
    for bad in (0.3, 0.0, -1.0, float("nan"), 2.0 ** 9):
        with pytest.raises(ValueError):
            packed_step_code(bad)
    with pytest.raises(ValueError):
        packed_step(256)


def power_law(seed: int, count: int = 75) -> np.ndarray:
    """Coefficients whose spread falls as a power of the vector's rank, as a shared basis' do."""
    return 140.0 * np.arange(1, count + 1) ** -1.1 * np.random.default_rng(seed).standard_normal(count)


@pytest.mark.parametrize("layer_bytes", [8, 13, 29, 61])
def test_packing_beats_int8_in_the_same_bytes(layer_bytes: int) -> None:
    """In the bytes of k int8 coefficients (a float16 step and k bytes), a packed layer holds more coefficients
    and leaves a smaller squared error of the sum, on coefficients that fall as a basis' do."""
    wins = 0
    for seed in range(20):
        c = power_law(seed)
        int8 = quantise_coefficients(SHA, c[:layer_bytes - 2])
        int8_error = ((c[:int8.count] - int8.coefficients()) ** 2).sum() + (c[int8.count:] ** 2).sum()
        packed = packed_coefficients(SHA, c, layer_bytes)
        assert packed is not None and packed.nbytes <= layer_bytes
        packed_error = ((c[:packed.count] - packed.coefficients()) ** 2).sum() + (c[packed.count:] ** 2).sum()
        choice = choose_packing(c, 0, layer_bytes)
        assert choice is not None and np.isclose(choice.error, packed_error, rtol=1e-4)
        wins += packed_error < int8_error and packed.count > int8.count
    assert wins >= 18


def test_a_packed_layer_validates_its_fields_and_count() -> None:
    step = packed_step(128)
    BasisLayer(SHA, step, np.array([255, -128, 63]), 0, 0, 9)
    with pytest.raises(ValueError, match="does not fit"):
        BasisLayer(SHA, step, np.array([256, 0, 0]), 0, 0, 9)
    with pytest.raises(ValueError, match="holds fewer"):
        BasisLayer(SHA, step, np.zeros(3, dtype=np.int64), 0, 0, 1)
    with pytest.raises(ValueError, match="packed step"):
        BasisLayer(SHA, 0.3, np.zeros(3, dtype=np.int64), 0, 0, 9)
    with pytest.raises(ValueError, match="top width"):
        BasisLayer(SHA, step, np.zeros(3, dtype=np.int64), 0, 0, 25)


def test_packed_records_round_trip_and_the_file_states_version_2_3() -> None:
    packed = BasisLayer(SHA, packed_step(100), np.array([25, -17, 0, 9, -2, 1]), 8, 0, 9)
    mu = np.linspace(-1, 1, 8).astype(np.float32)
    records = [
        LayeredRecord("a", mu, np.ones(8), basis=packed, compact_mu=True, fixed_mu_grid=True, store_sigma=False),
        LayeredRecord.without_latent("b", 8, BasisLayer(SHA, packed_step(130), np.array([-300, 90, 4]), 0, 0, 10)),
    ]
    data = encode_bvae(records, DECODER)
    assert (data[8], data[10]) == (2, 3)
    parsed = parse_bvae(data)
    for record, back in zip(records, parsed.records, strict=True):
        assert back.basis.top == record.basis.top and back.basis.first == record.basis.first
        assert back.basis.q.tolist() == record.basis.q.tolist() and back.basis.step == record.basis.step
        assert np.array_equal(back.basis.coefficients(), record.basis.coefficients())
    entry = parsed.header.entries[0]
    assert entry.length == 8 + packed.nbytes == 8 + 1 + 5  # μ on the grid, step code, 33 bits
    # the same records with int8 layers need no 2.3 reader
    int8 = [LayeredRecord("a", mu, np.ones(8), basis=quantise_coefficients(SHA, [1.0, 2.0], 8), store_sigma=False)]
    assert encode_bvae(int8, DECODER)[10] == 2


@pytest.mark.slow
def test_rate_control_packs_within_the_budget_and_beats_int8(analytic_tables) -> None:
    """At 16 and 32 B, the packed records fit the budget with more coefficients and no more error than int8."""
    from brdfcodec.codec import BrdfEncoder, measure

    brdf = analytic_tables["red-plastic"]
    for budget in (16, 32):
        errors = {}
        for coding in ("packed", "int8"):
            encoder = BrdfEncoder(effort=1, bytes=budget, latent_dtype="float16", project_base="never",
                                  basis_coding=coding)
            record = encoder.encode(brdf, name="m")
            assert record.meta["rate"]["record_bytes"] <= budget
            assert record.basis is not None and bool(record.basis.top) == (coding == "packed")
            entry = parse_bvae(encode_bvae([record], encoder.reference, latent_dtype="float16")).header.entries[0]
            assert entry.length + entry.descriptor_bytes == record.meta["rate"]["record_bytes"]
            errors[coding] = (measure(record, encoder.decoder, brdf).meta["relae"]["mapped"], record.basis.count)
        assert errors["packed"][1] > errors["int8"][1]
        assert errors["packed"][0] <= errors["int8"][0] * 1.02


def same_layer(a: BasisLayer | None, b: BasisLayer | None) -> bool:
    """Whether two basis layers store the same bytes on the same vectors."""
    return a is not None and b is not None and a.entry() == b.entry() and a.data == b.data


@pytest.mark.slow
def test_an_edit_keeps_a_packed_layer_and_undoing_it_returns_the_decode(red_plastic_file, tmp_path) -> None:
    """Edits move μ and keep the layers (§4.4): a packed basis layer is copied as it is, and moving μ back
    decodes to the source record's slices, guarded as every edit's are (§6 step 6)."""
    from brdfcodec.cli.main import main
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import read_bvae

    packed, edited, undone = tmp_path / "p.bvae", tmp_path / "e.bvae", tmp_path / "u.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(packed), "--bytes", "32", "--latent", "always",
                 "--basis-coding", "packed", "--no-measure"]) == 0
    (source,) = read_bvae(packed).records
    assert source.basis is not None and source.basis.top
    assert main(["edit", "traverse", str(packed), "--dim", "2", "--values", "0.5", "-o", str(edited)]) == 0
    (moved,) = read_bvae(edited).records
    assert same_layer(moved.basis, source.basis) and not np.array_equal(moved.mu, source.mu)
    assert main(["edit", "traverse", str(edited), "--dim", "2", "--values", repr(float(source.mu[1])), "--absolute",
                 "-o", str(undone)]) == 0
    (restored,) = read_bvae(undone).records
    assert same_layer(restored.basis, source.basis) and np.array_equal(restored.mu, source.mu)
    from brdfcodec.representation.highlight_guard import guard_highlight

    decoder = BrdfDecoder()
    np.testing.assert_array_equal(decoder.mapped_record(restored, energy_bound=False),
                                  guard_highlight(decoder.mapped_record(source, energy_bound=False)))
