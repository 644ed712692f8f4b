"""Issue 14: refinement, the detail layer, layered records in the format, rate control, edits on layered records."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from bvae_bytes import bytes_writer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from brdfcodec.conventions import NETWORK_INPUT_SHAPE
from brdfcodec.errors import BvaeFormatError, RateTargetError, UnsupportedVersionError
from brdfcodec.format.bvae import (
    FORMAT_MAJOR,
    DecoderReference,
    LatentRecord,
    encode_bvae,
    parse_bvae,
)
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.layers.detail import DetailLayer, decode_detail, encode_detail

DECODER = DecoderReference("ab" * 32, "test-decoder")


def smooth_residual(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    h = np.linspace(0, 1, 90)
    field = np.sin(3 * h[:, None] + rng.normal()) * np.cos(2 * h[None, :]) * 0.2
    return (field[None] * rng.normal(1, 0.3, size=(63, 1, 1))).astype(np.float32) + rng.normal(
        0, 0.01, NETWORK_INPUT_SHAPE
    ).astype(np.float32)


def layered(step: float = 0.05, name: str = "layered-0") -> LayeredRecord:
    rng = np.random.default_rng(1)
    return LayeredRecord(name, rng.normal(size=8), np.full(8, 0.1), {"effort": 1},
                         detail=encode_detail(smooth_residual(), step))


@pytest.mark.parametrize("step", [0.01, 0.1, 1.0])
@pytest.mark.slow
def test_detail_error_is_bounded_by_the_step(step: float) -> None:
    residual = smooth_residual()
    layer = encode_detail(residual, step)
    decoded = decode_detail(layer).reshape(NETWORK_INPUT_SHAPE)
    rms = float(np.sqrt(np.mean((decoded - residual) ** 2)))
    assert rms <= step / np.sqrt(12) * 1.05  # orthonormal transforms: the quantisation noise, no more
    assert layer.nbytes < residual.nbytes


def test_detail_sizes_fall_as_the_step_grows() -> None:
    residual = smooth_residual()
    sizes = [encode_detail(residual, s).nbytes for s in (0.005, 0.05, 0.5)]
    assert sizes[0] > sizes[1] > sizes[2]


@pytest.mark.slow
def test_partial_detail_equals_the_same_slots_of_the_full_one() -> None:
    layer = encode_detail(smooth_residual(), 0.02)
    full = decode_detail(layer)
    np.testing.assert_allclose(decode_detail(layer, [0, 7, 20]), full[:, [0, 7, 20]], atol=1e-5)


@pytest.mark.slow
def test_large_residuals_switch_to_int32() -> None:
    assert encode_detail(smooth_residual() * 40, 1e-4).dtype == "int32"


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_layered_records_round_trip_with_plain_ones(dtype: str) -> None:
    plain = LatentRecord("plain", np.zeros(8), np.ones(8))
    record = layered()
    data = encode_bvae([plain, record], DECODER, latent_dtype=dtype)  # type: ignore[arg-type]
    library = parse_bvae(data)
    assert (library.header.major, library.header.minor) == (FORMAT_MAJOR, 1)  # 2.1: the lowest version that holds it
    back = library.record("layered-0")
    assert isinstance(back, LayeredRecord) and back.detail == record.detail
    assert library.header.entries[1].length == 2 * 8 * (2 if dtype == "float16" else 4) + record.detail.nbytes
    assert type(library.record("plain")) is LatentRecord


def test_unknown_layers_and_transforms_are_unsupported_and_bad_fields_malformed() -> None:
    record = layered()
    frame = record.detail.data
    payload = np.concatenate([record.mu, record.sigma]).astype("<f4").tobytes() + frame
    writer = bytes_writer

    def layered_file(form: bytes, step: float = 0.05, length: int = len(frame)) -> bytes:
        stored = writer.header([form], [writer.descriptor("l", 0, step=step, detail_length=length)], payload, dim=8)
        return writer.assemble(stored, payload)

    assert parse_bvae(layered_file(writer.layered_form(detail=0))).records[0].detail == record.detail
    with pytest.raises(UnsupportedVersionError, match="layers"):
        parse_bvae(layered_file(writer.layered_form(detail=0, layer_bits=2 | 16)))  # an unknown layer (bit 3: 2.4)
    with pytest.raises(UnsupportedVersionError, match="detail form 7"):
        parse_bvae(layered_file(writer.layered_form(detail=7)))  # an unknown transform or coefficient type
    with pytest.raises(BvaeFormatError, match="neither"):
        parse_bvae(layered_file(writer.layered_form(layer_bits=0)))
    for bad in ({"step": -1.0}, {"step": float("nan")}, {"step": 101.0}, {"length": 0}):
        with pytest.raises(BvaeFormatError):
            parse_bvae(layered_file(writer.layered_form(detail=0), **bad))


def test_a_layer_that_is_not_the_declared_frame_is_refused() -> None:
    record = layered()
    bogus = LayeredRecord("x", record.mu, record.sigma, detail=DetailLayer(0.05, "int16", b"not zstd at all"))
    with pytest.raises(BvaeFormatError, match="zstandard"):
        parse_bvae(encode_bvae([bogus], DECODER))


def _with_basis_from_vector_8() -> LayeredRecord:
    from brdfcodec.layers.basis import BasisLayer

    return LayeredRecord("basis-8", np.zeros(8), np.ones(8), basis=BasisLayer("cd" * 32, 0.5, np.arange(
        -3, 4, dtype=np.int8), 8), compact_sigma=True)


def _with_compact_base() -> LayeredRecord:
    from brdfcodec.layers.basis import BasisLayer

    return LayeredRecord("compact", np.linspace(-2, 2, 8), np.full(8, 0.003), basis=BasisLayer(
        "cd" * 32, 0.25, np.arange(-2, 3, dtype=np.int8), 8), compact_mu=True, shared_sigma=True)


def _with_fixed_grid_base() -> LayeredRecord:
    from brdfcodec.layers.basis import BasisLayer

    return LayeredRecord("fixed", np.linspace(-3, 3, 8), np.full(8, 0.003), basis=BasisLayer(
        "cd" * 32, 0.25, np.arange(-2, 3, dtype=np.int8), 8), compact_mu=True, shared_sigma=True, fixed_mu_grid=True)


def _with_projected_base() -> LayeredRecord:
    from brdfcodec.layers.basis import BasisLayer

    return LayeredRecord("projected", np.linspace(-1, 1, 8), np.full(8, 0.003), basis=BasisLayer(
        "cd" * 32, 0.25, np.arange(-2, 3, dtype=np.int8), 8, 50), compact_mu=True, shared_sigma=True,
        fixed_mu_grid=True)


# A detail layer, (format 1.3) a basis layer starting at vector 8, (1.4) compact μ with the shared σ byte,
# (1.5) compact μ on the fixed grid and (1.6) a projected base: mutations hit every entry.
_VALID = encode_bvae([layered(0.5), _with_basis_from_vector_8(), _with_compact_base(), _with_fixed_grid_base(),
                      _with_projected_base()], DECODER)


@settings(max_examples=150, suppress_health_check=[HealthCheck.too_slow], deadline=None)
@given(st.lists(st.tuples(st.integers(0, len(_VALID) - 1), st.integers(1, 255)), min_size=1, max_size=6))
def test_fuzz_mutations_of_a_layered_file(changes: list[tuple[int, int]]) -> None:
    """Every byte of a file is under a CRC-32 (header or payload): any change is refused, as a typed error."""
    data = bytearray(_VALID)
    for position, xor in changes:
        data[position] ^= xor
    if bytes(data) == _VALID:  # the changes cancelled out
        assert len(parse_bvae(bytes(data)).records) == 5
        return
    with pytest.raises(BvaeFormatError):  # checksum, version and malformed-file errors are all BvaeFormatErrors
        parse_bvae(bytes(data))


@pytest.mark.slow
def test_rate_control_meets_budgets_and_targets(analytic_tables) -> None:
    from brdfcodec.codec import BrdfEncoder, measure

    brdf = next(iter(analytic_tables.values()))
    for budget in (64, 2000, 20000):
        encoder = BrdfEncoder(effort=0, bytes=budget)
        record = encoder.encode(brdf, name="m")
        entry = parse_bvae(encode_bvae([record], encoder.reference)).header.entries[0]
        assert entry.length == record.meta["rate"]["payload_bytes"]
        assert entry.length + entry.descriptor_bytes == record.meta["rate"]["record_bytes"] <= budget
    encoder = BrdfEncoder(effort=0, max_relae=0.02)
    record = measure(encoder.encode(brdf, name="m"), encoder.decoder, brdf)
    assert record.meta["relae"]["mapped"] <= 0.02
    # below the smallest layered record with a latent (11 B with a one-byte name, μ coded in the layer's stream,
    # format 2.5; 14 B with μ on the fixed grid): the compact base alone, 10 B
    alone = BrdfEncoder(effort=0, bytes=10, latent="always").encode(brdf, name="m")
    assert isinstance(alone, LayeredRecord) and alone.basis is None and alone.detail is None
    assert alone.compact_mu and alone.meta["rate"]["record_bytes"] == 10
    with pytest.raises(RateTargetError):  # below that (without a latent, from 6 B: test_basis_only.py)
        BrdfEncoder(effort=0, bytes=9, latent="always").encode(brdf, name="m")


@pytest.mark.slow
def test_refinement_never_worsens_and_edits_keep_the_layers(analytic_tables) -> None:
    from brdfcodec.codec import BrdfEncoder, measure
    from brdfcodec.edit.latent_edits import interpolate, traverse

    brdf = next(iter(analytic_tables.values()))
    errors = []
    for effort in (0, 1):
        encoder = BrdfEncoder(effort=effort)
        errors.append(measure(encoder.encode(brdf, name="m"), encoder.decoder, brdf).meta["relae"]["mapped"])
    assert errors[1] <= errors[0] + 1e-6
    encoder = BrdfEncoder(effort=0, bytes=4000)
    record = encoder.encode(brdf, name="m")
    assert isinstance(record, LayeredRecord)
    edited = traverse(record, 0, [0.5])[0]  # spec §4.4: an edit moves μ and keeps the record's layers
    assert isinstance(edited, LayeredRecord) and edited.detail is record.detail and edited.basis is record.basis
    assert edited.mu[0] != record.mu[0] and np.array_equal(edited.mu[1:], record.mu[1:])
    mixed = interpolate(record, LatentRecord("b", np.zeros(8), np.ones(8)), 0.5)
    assert isinstance(mixed, LayeredRecord) and mixed.detail is record.detail and mixed.basis is record.basis


@pytest.mark.slow
def test_layered_decode_adds_the_layer_and_partial_decode_matches(analytic_tables) -> None:
    from brdfcodec.codec import BrdfEncoder

    brdf = next(iter(analytic_tables.values()))
    encoder = BrdfEncoder(effort=0, bytes=20000)
    record = encoder.encode(brdf, name="m")
    decoder = encoder.decoder
    full = decoder.decode(record, masked="zero")
    base = decoder.decode(record.base(), masked="zero")
    assert not np.allclose(full, base)
    part = decoder.decode(record, phi_d_bins=[4, 100], masked="zero")
    np.testing.assert_allclose(part, full[..., [4, 100]], rtol=1e-4, atol=1e-4)
    batched = next(decoder.decode_many([record], masked="zero"))
    np.testing.assert_allclose(batched, full, rtol=1e-5, atol=1e-5)
    # The detail layer is decoded on a second thread beside the basis sum: its errors reach the caller.
    broken = dataclasses.replace(record, detail=DetailLayer(0.05, "int16", b"not zstd at all"))
    with pytest.raises(ValueError, match="cannot be decompressed"):
        decoder.decode(broken)
    np.testing.assert_array_equal(decoder.decode(record, masked="zero"), full)


@pytest.mark.slow
def test_cli_rate_control_flags(red_plastic_file, tmp_path, capsys) -> None:
    from brdfcodec.cli import main
    from brdfcodec.format.bvae import read_bvae

    out = tmp_path / "m.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(out), "--bytes", "3000", "--float16",
                 "--effort", "0", "--provenance"]) == 0
    record = read_bvae(out).records[0]
    assert isinstance(record, LayeredRecord) and record.meta["rate"]["record_bytes"] <= 3000
    assert record.meta["effort"] == 0
    assert main(["compress", str(red_plastic_file), "-o", str(out), "--force", "--max-relae", "0.03",
                 "--metric", "linear", "--effort", "0", "--provenance"]) == 0
    assert read_bvae(out).records[0].meta["relae"]["linear"] <= 0.03
    capsys.readouterr()
    bad = tmp_path / "bad.bvae"
    # a budget below every record with a latent (from 6 B without one: test_basis_only.py)
    assert main(["compress", str(red_plastic_file), "-o", str(bad), "--bytes", "9", "--latent", "always"]) == 2
    assert "below the smallest record" in capsys.readouterr().err and not bad.exists()
    assert main(["compress", str(red_plastic_file), "-o", str(bad), "--bytes", "100", "--max-relae", "0.1"]) == 2
    assert main(["compress", str(red_plastic_file), "-o", str(bad), "--effort", "7"]) == 2


@pytest.mark.slow
def test_refinement_adam_matches_torch_optim() -> None:
    """The hand-written Adam of refine.py (no torch._dynamo import) follows torch.optim.Adam step for step."""
    import torch

    from brdfcodec.codec.refine import _Adam

    torch.manual_seed(0)
    start = torch.randn(3, 8)
    ours, theirs = start.clone().requires_grad_(True), start.clone().requires_grad_(True)
    mine, reference = _Adam(ours, 0.05), torch.optim.Adam([theirs], lr=0.05)
    for _ in range(6):
        for z in (ours, theirs):
            z.grad = None
            (z.sin() * torch.arange(8.0)).sum().backward()
        mine.step()
        reference.step()
        torch.testing.assert_close(ours, theirs, rtol=1e-6, atol=1e-7)
    assert not torch.equal(ours.detach(), start)


@pytest.mark.parametrize("flags", [["--bytes", "0"], ["--bytes", "-5"], ["--max-relae", "0"], ["--max-relae", "nan"],
                                   ["--max-relae", "inf"], ["--max-relae", "-0.1"], ["--batch-size", "0"],
                                   ["--metric", "linear"]])
def test_cli_bad_flag_values_are_usage_errors(red_plastic_file, tmp_path, capsys, flags) -> None:
    from brdfcodec.cli import main

    out = tmp_path / "m.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(out), *flags]) == 2
    err = capsys.readouterr().err
    assert flags[0] in err and "Traceback" not in err and not out.exists()


@pytest.mark.slow
def test_cli_graft_fit_of_a_layered_record_starts_from_its_base(red_plastic_file, tmp_path, capsys) -> None:
    """`bvae edit graft --fit` compares the fitted graft with the base code it starts from, not the layered decode."""
    from brdfcodec.cli import main
    from brdfcodec.codec import BrdfDecoder, measure
    from brdfcodec.format.bvae import read_bvae
    from brdfcodec.io.merl import read_merl

    layered_file, fitted = tmp_path / "m.bvae", tmp_path / "f.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(layered_file), "--bytes", "3000", "--effort", "0",
                 "--latent", "always", "--provenance"]) == 0  # the record's RelAE is stored only with --provenance
    record = read_bvae(layered_file).records[0]
    assert isinstance(record, LayeredRecord)
    base_relae = measure(record.base(), BrdfDecoder(), read_merl(red_plastic_file)).meta["relae"]["mapped"]
    assert record.meta["relae"]["mapped"] < base_relae - 1e-3  # the two differ: the message tells which
    capsys.readouterr()
    assert main(["edit", "graft", str(layered_file), "--fit", str(red_plastic_file), "-o", str(fitted)]) == 0
    out = capsys.readouterr().out
    assert f"{base_relae:.4f} from the code alone" in out
    after = float(out.split(" with the fitted graft")[0].rsplit(" ", 1)[1])
    # The better of the two is written: the graft where it wins, else the code alone (with a warning).
    expected = "GraftRecord" if after < base_relae else "LatentRecord"
    assert type(read_bvae(fitted).records[0]).__name__ == expected


def test_cli_reference_that_reflects_nothing_is_bad_input(tmp_path, capsys) -> None:
    from brdfcodec.cli import main
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.datasets.analytic import AnalyticBRDF
    from brdfcodec.format.bvae import write_bvae
    from brdfcodec.io.merl import write_merl

    decoder = BrdfDecoder()
    lib = tmp_path / "one.bvae"
    write_bvae(lib, [LatentRecord("m", np.zeros(decoder.latent_dim), np.ones(decoder.latent_dim))], decoder.reference)
    black = tmp_path / "black.binary"
    write_merl(black, AnalyticBRDF("black", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.3).to_merl())
    code = main(["decompress", str(lib), "-o", str(tmp_path / "m.npy"), "--phi-d", "0", "--reference", str(black)])
    err = capsys.readouterr().err
    assert code == 1 and f"error: {black}: the reference reflects nothing" in err and "Traceback" not in err
    assert not (tmp_path / "m.npy").exists()  # measured before writing: no output from a failed command


def test_measure_sets_the_provenance_of_the_source_it_measured_against(analytic_tables) -> None:
    from dataclasses import replace

    from brdfcodec.codec import BrdfDecoder, measure

    decoder = BrdfDecoder()
    brdf = next(iter(analytic_tables.values()))
    rgl = replace(brdf, source_kind="rgl-measured", source_sha256="7" * 64)
    record = LatentRecord("m", np.zeros(decoder.latent_dim), np.ones(decoder.latent_dim), {"note": 1})
    measured = measure(record, decoder, rgl)
    assert measured.meta["source_kind"] == "rgl-measured" and measured.meta["source_sha256"] == "7" * 64
    again = measure(measured, decoder, brdf)  # now against a MERL table: no source_kind left from the RGL one
    assert "source_kind" not in again.meta and again.meta["source_sha256"] == brdf.sha256
    assert again.meta["note"] == 1


@pytest.mark.parametrize("better", [32, 64, 75])
@pytest.mark.slow
def test_a_record_with_a_detail_layer_carries_at_most_the_largest_detail_basis_count(better: int) -> None:
    """Under a budget with room for detail, all 75 coefficients are tried without detail and 32 and 64 with it
    (the cap bounds every layered record's decode time), and the lowest error is kept."""
    from brdfcodec.codec.rate import DETAIL_BASIS_COUNTS, encode_layers
    from brdfcodec.layers.basis import quantise_coefficients

    rng = np.random.default_rng(5)
    target = rng.uniform(0.0, 1.0, NETWORK_INPUT_SHAPE).astype(np.float32)
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", np.zeros(8), np.ones(8))
    fitted: list[tuple[int, bool]] = []

    def fit(k: int, mu_storage: str | None, under_detail: bool):  # noqa: ANN202 - the BasisFit callable
        # 4096 B hold all 75 coefficients beside μ in float32; the compact base's best is only a candidate (issue 39)
        assert mu_storage is None or (k == 75 and not under_detail)
        fitted.append((k, under_detail))
        # how much of the material k coefficients explain: 75 without detail can beat 32 or 64 with it
        share = 0.999 if k == better else 0.5
        return base, quantise_coefficients("cd" * 32, np.ones(k)), (target * share).astype(np.float32)

    budget = 4096
    result = encode_layers(base, np.zeros_like(target), target, masks, bytes_budget=budget, basis_fit=fit,
                           basis_count=75)
    assert DETAIL_BASIS_COUNTS == (32, 64)
    assert sorted(set(fitted)) == [(32, True), (64, True), (75, False)]
    record = result.record
    assert isinstance(record, LayeredRecord) and result.payload_bytes <= budget
    assert record.basis.count == better
    assert (record.detail is not None) == (better in DETAIL_BASIS_COUNTS)


@pytest.mark.parametrize("all_coefficients_meet_it", [True, False])
@pytest.mark.slow
def test_an_error_target_searches_records_without_detail_first(all_coefficients_meet_it: bool) -> None:
    """The detail ladder carries at most 32 coefficients, so its coarse rungs can be worse than all 75 without
    detail: the search keeps to the records without detail when the largest of them meets the target."""
    from brdfcodec.codec.rate import DETAIL_BASIS_COUNT, encode_layers
    from brdfcodec.layers.basis import quantise_coefficients
    from brdfcodec.representation import network_input_from_table

    values = np.full((3, 90, 90, 180), 0.05)
    mask = np.ones(values.shape, dtype=bool)
    inputs, input_mask = network_input_from_table(values, mask)
    base = LatentRecord("m", np.zeros(8), np.ones(8))

    def fit(k: int, mu_storage: str | None, under_detail: bool):  # noqa: ANN202, ARG001 - the BasisFit callable
        exact = k == 75 and not under_detail and all_coefficients_meet_it
        mapped = inputs if exact else inputs * np.float32(0.7)  # only all 75 coefficients explain the material
        return base, quantise_coefficients("cd" * 32, np.ones(k)), mapped.astype(np.float32)

    result = encode_layers(base, inputs * np.float32(0.7), inputs, input_mask.astype(np.float32), values=values,
                           mask=mask, max_relae=0.01, basis_fit=fit, basis_count=75)
    record = result.record
    assert isinstance(record, LayeredRecord)
    if all_coefficients_meet_it:
        assert record.basis.count == 75 and record.detail is None
        assert all(step is None for step, _, _ in result.tried)  # no detail candidate was needed
    else:
        assert record.basis.count == DETAIL_BASIS_COUNT and record.detail is not None


@pytest.mark.parametrize(("budget", "itemsize", "mu_max", "storage", "count"), [
    # Each budget counts the record's 3-byte descriptor (name length, form, coefficient count) beside its payload.
    (15, 4, 1.0, "int8-fixed", 1),  # the smallest layered record: 9 B of compact base, the step, one coefficient
    (17, 4, 5.0, "int8", 1),  # μ past the fixed grid's ±3.97: its own step, 2 bytes more
    (16, 4, 5.0, "int8-fixed", 2),  # ... unless the step does not fit: then the grid's end holds μ
    (32, 2, 1.0, "int8-fixed", 18),
    (32, 2, 5.0, "int8", 16),
    (64, 4, 1.0, "int8-fixed", 50),  # compact whatever the latent dtype
    (91, 4, 1.0, "int8-fixed", 75),  # 75 coefficients only fit beside a compact base (40 + 2 + 75 + 3 = 120 B else)
    (120, 4, 1.0, None, 75),  # all 75 fit beside μ in float32 and σ bytes: the base keeps its full precision
    (104, 2, 5.0, None, 75),
])
def test_a_budget_too_small_for_every_coefficient_stores_a_compact_base(
    budget: int, itemsize: int, mu_max: float, storage: str | None, count: int
) -> None:
    from brdfcodec.codec.rate import encode_layers
    from brdfcodec.layers.basis import quantise_coefficients

    target = np.full(NETWORK_INPUT_SHAPE, 0.5, dtype=np.float32)
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", np.linspace(-mu_max, mu_max, 8), np.full(8, 0.003))
    fitted: list[tuple[int, str | None]] = []

    def fit(k: int, mu_storage: str | None, under_detail: bool):  # noqa: ANN202, ARG001 - the BasisFit callable
        fitted.append((k, mu_storage))
        return base, quantise_coefficients("cd" * 32, np.ones(k)), target * 0.9

    result = encode_layers(base, np.zeros_like(target), target, masks, bytes_budget=budget, basis_fit=fit,
                           basis_count=75, latent_itemsize=itemsize)
    record = result.record
    compact = storage is not None
    assert isinstance(record, LayeredRecord) and record.basis.count == count
    assert record.compact_mu == record.shared_sigma == compact and record.compact_sigma != compact
    assert record.fixed_mu_grid == (storage == "int8-fixed")
    # One basis size only: beside 32 coefficients none of these budgets has room for a detail layer (49 B at least).
    # Past the compact budgets the compact base's best (all 75 on a compact μ) stays a candidate too, so that rate
    # control stays monotone (issue 39); on a tie the full-precision base is kept.
    from brdfcodec.codec.rate import compact_mu_storage

    assert set(fitted) == {(count, storage)} | (set() if compact else {(count, compact_mu_storage(base.mu))})
    stored = parse_bvae(encode_bvae([record], DECODER, latent_dtype="float32" if itemsize == 4 else "float16"))
    entry = stored.header.entries[0]
    assert entry.length + entry.descriptor_bytes == result.payload_bytes <= budget
    if compact:  # a compact μ holds what is stored
        assert stored.records[0].mu.tolist() == record.mu.tolist()
    smallest = budget if count == 1 and storage == "int8-fixed" else None  # μ's own step falls back to the grid
    if smallest is not None:
        with pytest.raises(RateTargetError, match=f"{smallest - 1} bytes is below the base record's {smallest} bytes"):
            encode_layers(base, np.zeros_like(target), target, masks, bytes_budget=smallest - 1, basis_fit=fit,
                          basis_count=75)
