"""Issue 14: the basis layer (coefficients on the model's shared basis) and compact sigma (spec §4.5)."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.errors import BasisMismatchError, BvaeFormatError
from brdfcodec.format.bvae import DecoderReference, LatentRecord, encode_bvae, parse_bvae
from brdfcodec.format.layered_record import LayeredRecord, quantise_sigma, sigma_from_codes
from brdfcodec.layers.basis import (
    BasisError,
    BasisLayer,
    SharedBasis,
    fit_shared_basis,
    load_shared_basis,
    quantise_coefficients,
    shared_basis_rank,
    with_colour_permutations,
    write_shared_basis,
)

DECODER = DecoderReference("ab" * 32, "test-decoder")
SHA = "cd" * 32


def basis_record(name: str = "b", k: int = 5, *, compact: bool = True, sha: str = SHA) -> LayeredRecord:
    rng = np.random.default_rng(3)
    layer = quantise_coefficients(sha, rng.normal(0, 4, size=k))
    return LayeredRecord(name, rng.normal(size=8), np.exp(rng.normal(-2, 1, size=8)), {"effort": 1},
                         basis=layer, compact_sigma=compact)


def test_quantised_coefficients_are_within_half_a_step() -> None:
    c = np.array([40.0, -3.2, 0.01, 0.0, -40.5])
    layer = quantise_coefficients(SHA, c)
    assert np.float16(layer.step) == layer.step and layer.step > 0
    assert np.abs(layer.coefficients() - c).max() <= layer.step / 2 * 1.001
    assert np.abs(layer.q).max() <= 127
    assert layer.nbytes == len(layer.data) == 2 + len(c)
    assert quantise_coefficients(SHA, np.zeros(3)).coefficients().tolist() == [0.0, 0.0, 0.0]  # no division by 0


def test_compact_sigma_is_within_its_bound_and_stable() -> None:
    sigma = np.exp(np.linspace(np.log(3e-4), np.log(12.0), 200))
    stored = sigma_from_codes(quantise_sigma(sigma))
    assert np.abs(stored / sigma - 1).max() <= 2 ** (1 / 32) - 1 + 1e-6  # half a 1/16 octave: 2.2 %
    np.testing.assert_array_equal(sigma_from_codes(quantise_sigma(stored)), stored)  # re-encoding changes nothing


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_basis_records_round_trip_and_cost_what_the_spec_says(dtype: str) -> None:
    plain = LatentRecord("plain", np.zeros(8), np.ones(8))
    record = basis_record()
    parsed = parse_bvae(encode_bvae([plain, record], DECODER, latent_dtype=dtype))  # type: ignore[arg-type]
    entry = parsed.header.entries[1]
    itemsize = 2 if dtype == "float16" else 4
    assert entry.length == 8 * itemsize + 8 + 2 + 5  # mu, sigma as bytes, step, coefficients
    assert entry.layers == {"sigma": "log2-u8", "basis": {"sha256": SHA, "count": 5}}
    back = parsed.records[1]
    assert isinstance(back, LayeredRecord) and back.compact_sigma and back.detail is None
    np.testing.assert_array_equal(back.basis.q, record.basis.q)
    assert back.basis.step == record.basis.step
    np.testing.assert_array_equal(back.sigma, record.sigma)  # the record already holds the stored widths
    wide = LayeredRecord("w", record.mu, record.sigma, basis=record.basis)
    assert parse_bvae(encode_bvae([wide], DECODER)).header.entries[0].length == 16 * 4 + 7


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_compact_mu_and_shared_sigma_round_trip_in_eleven_bytes(dtype: str) -> None:
    rng = np.random.default_rng(4)
    mu, sigma = rng.normal(0, 1.5, size=8), np.exp(rng.normal(-6, 0.6, size=8))
    layer = quantise_coefficients(SHA, rng.normal(0, 4, size=19), 8)
    record = LayeredRecord("c", mu, sigma, {"effort": 1}, basis=layer, compact_mu=True, shared_sigma=True)
    step = np.abs(mu).max() / 127
    assert np.abs(record.mu - mu).max() <= step / 2 * 1.01  # μ within half a step of max |μ| / 127
    geometric_mean = np.exp2(np.log2(sigma).mean())
    assert np.allclose(record.sigma, record.sigma[0]) and abs(record.sigma[0] / geometric_mean - 1) <= 0.022
    data = encode_bvae([record], DECODER, latent_dtype=dtype)  # type: ignore[arg-type]
    parsed = parse_bvae(data)
    entry = parsed.header.entries[0]
    assert entry.length == 2 + 8 + 1 + 2 + 19 == 32  # the same in either latent dtype: nothing is stored in it
    assert entry.layers == {"mu": "int8", "sigma": "log2-u8-shared", "basis": layer.entry()}
    back = parsed.records[0]
    assert isinstance(back, LayeredRecord) and back.compact_mu and back.shared_sigma
    np.testing.assert_array_equal(back.mu, record.mu)
    np.testing.assert_array_equal(back.sigma, record.sigma)
    assert encode_bvae([back], DECODER, latent_dtype=dtype) == data  # re-encoding changes nothing  # type: ignore[arg-type]
    only_mu = LayeredRecord("m", mu, sigma, basis=layer, compact_mu=True)  # σ stays in the latent dtype
    itemsize = 4 if dtype == "float32" else 2
    assert parse_bvae(encode_bvae([only_mu], DECODER, latent_dtype=dtype)).records[0].sigma.tolist() == pytest.approx(  # type: ignore[arg-type]
        sigma.astype(np.float16 if itemsize == 2 else np.float32).tolist())
    with pytest.raises(ValueError, match="either per dimension or shared"):
        LayeredRecord("x", mu, sigma, basis=layer, compact_sigma=True, shared_sigma=True)


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_compact_mu_on_the_fixed_grid_round_trips_in_nine_bytes(dtype: str) -> None:
    from brdfcodec.layers.basis import FIXED_MU_LIMIT, fits_fixed_mu_grid

    rng = np.random.default_rng(6)
    mu, sigma = rng.uniform(-3.9, 3.9, size=8), np.exp(rng.normal(-6, 0.6, size=8))
    layer = quantise_coefficients(SHA, rng.normal(0, 4, size=21), 8)
    record = LayeredRecord("g", mu, sigma, basis=layer, compact_mu=True, shared_sigma=True, fixed_mu_grid=True)
    assert np.abs(record.mu - mu).max() <= 1 / 64 + 1e-7  # within half the grid's step
    assert np.array_equal(record.mu * 32, np.rint(mu * 32))  # μ = q / 32, exactly
    data = encode_bvae([record], DECODER, latent_dtype=dtype)  # type: ignore[arg-type]
    parsed = parse_bvae(data)
    entry = parsed.header.entries[0]
    assert entry.length == 8 + 1 + 2 + 21 == 32  # no step: 2 more coefficients than the 11-byte base holds
    assert entry.layers == {"mu": "int8-fixed", "sigma": "log2-u8-shared", "basis": layer.entry()}
    back = parsed.records[0]
    assert isinstance(back, LayeredRecord) and back.fixed_mu_grid and back.compact_mu
    np.testing.assert_array_equal(back.mu, record.mu)
    assert encode_bvae([back], DECODER, latent_dtype=dtype) == data  # type: ignore[arg-type]
    # Past ±3.97 a value is stored as the grid's end (an encoder uses the grid only where μ fits it).
    assert fits_fixed_mu_grid(mu) and not fits_fixed_mu_grid([4.0]) and not fits_fixed_mu_grid([np.nan])
    clipped = LayeredRecord("c", np.array([-9.0, 9.0, 0.0, 0, 0, 0, 0, 0]), sigma, basis=layer, compact_mu=True,
                            fixed_mu_grid=True)
    assert clipped.mu[:2].tolist() == [-FIXED_MU_LIMIT, FIXED_MU_LIMIT]
    with pytest.raises(ValueError, match="fixed mu grid is a compact mu"):
        LayeredRecord("x", mu, sigma, basis=layer, fixed_mu_grid=True)


@pytest.mark.parametrize("step", [0.0, float("inf"), float("nan"), -0.5])
def test_a_compact_mu_step_that_is_not_positive_and_finite_is_malformed(step: float, monkeypatch) -> None:
    record = LayeredRecord("c", np.ones(8), np.ones(8), basis=quantise_coefficients(SHA, [1.0]), compact_mu=True,
                           shared_sigma=True)
    # The writer stores whatever step the record gives it (CRCs and lengths stay right): only the step is wrong.
    monkeypatch.setattr(LayeredRecord, "_mu_code", lambda self: (step, np.ones(8, dtype=np.int8)))
    data = encode_bvae([record], DECODER)
    with pytest.raises(BvaeFormatError, match="compact mu step"):
        parse_bvae(data)


def test_unknown_mu_and_sigma_storage_are_unsupported() -> None:
    from brdfcodec.format.layered_record import layers_length

    for layers, what in (({"mu": "int4", "basis": {"sha256": SHA, "count": 1}}, "mu"),
                         ({"sigma": "log2-u4", "basis": {"sha256": SHA, "count": 1}}, "sigma")):
        with pytest.raises(ValueError, match=f"stores {what} as") as raised:
            layers_length(layers, "record 0", 8)
        assert type(raised.value).__name__ == "UnsupportedLayerError"
    full = {"mu": "int8", "sigma": "log2-u8-shared", "basis": {"sha256": SHA, "count": 5}}
    assert layers_length(full, "record 0", 8) == (2 + 8) + 1 + (2 + 5)


def test_a_layered_record_needs_a_layer() -> None:
    with pytest.raises(ValueError, match="basis layer, a detail layer or both"):
        LayeredRecord("x", np.zeros(8), np.ones(8), compact_sigma=True)


def test_a_truncated_basis_payload_is_malformed() -> None:
    data = bytearray(encode_bvae([basis_record()], DECODER, compress_header=False))
    # The last byte is a coefficient: drop it and fix nothing else; the length no longer matches the layers.
    with pytest.raises(BvaeFormatError):
        parse_bvae(bytes(data[:-1]))


def synthetic_inputs(n: int = 6) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    h = np.linspace(0, 1, 90)
    shapes = [np.outer(np.sin((i + 1) * h), np.cos((i + 2) * h)) for i in range(3)]
    inputs = np.stack([sum(rng.normal() * s for s in shapes)[None].repeat(63, 0) + 1.0 for _ in range(n)])
    masks = np.ones(inputs.shape, dtype=bool)
    masks[:, :, :, 80:] = False  # entries invalid in every material are not covered
    masks[0, 0, 0, 0] = False  # nor one invalid in a single material
    return (inputs * masks).astype(np.float32), masks


def test_fitted_basis_is_orthonormal_over_the_valid_entries(tmp_path) -> None:
    inputs, masks = synthetic_inputs()
    components, entries = fit_shared_basis(inputs, masks, 3)
    assert components.dtype == np.float16 and components.shape == (3, len(entries))
    assert 0 not in entries and len(entries) == 63 * 90 * 80 - 1
    gram = components.astype(np.float64) @ components.astype(np.float64).T
    np.testing.assert_allclose(gram, np.eye(3), atol=2e-3)
    with pytest.raises(ValueError, match="count"):
        fit_shared_basis(inputs, masks, 6)  # rank of 6 centred materials is at most 5
    path = tmp_path / "basis.safetensors"
    sha = write_shared_basis(path, components, entries)
    basis = load_shared_basis(path, sha)
    assert basis.count == 3 and basis.sha256 == sha
    # Data in the span of the basis (plus the mean) is reproduced by its projection.
    mean = inputs.reshape(len(inputs), -1)[:, entries].mean(0)
    x = inputs[2].reshape(-1)[entries]
    c = components.astype(np.float32) @ (x - mean)
    rebuilt = basis.residual(c).reshape(-1)[entries] + mean
    assert np.abs(rebuilt - x).max() < 5e-3 * np.abs(x).max()
    np.testing.assert_allclose(basis.residual_channels(c, [5, 62]), basis.residual(c)[[5, 62]], atol=1e-6)
    with pytest.raises(BasisError, match="SHA-256"):
        load_shared_basis(path, "0" * 64)
    with pytest.raises(BasisError, match="strictly increasing"):
        write_shared_basis(tmp_path / "bad.safetensors", components, entries[::-1].copy())


def coloured_inputs(n: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Materials whose R, G and B blocks differ (a shape per colour, scaled per material)."""
    rng = np.random.default_rng(1)
    h = np.linspace(0, 1, 90)
    shapes = [np.outer(np.sin((c + 1) * h), np.cos((c + 3) * h)) for c in range(3)]
    inputs = np.concatenate([np.stack([rng.uniform(0.5, 2.0) * shapes[c][None].repeat(21, 0) + 0.1 * c
                                       for c in range(3)]).reshape(63, 90, 90)[None] for _ in range(n)])
    return inputs.astype(np.float32), np.ones(inputs.shape, dtype=bool)


def test_colour_permutations_exchange_whole_colour_blocks() -> None:
    inputs, _ = coloured_inputs(2)
    stacked = with_colour_permutations(inputs)
    assert stacked.shape == (12, 63, 90, 90)
    np.testing.assert_array_equal(stacked[:2], inputs)  # the materials as given come first
    # Order (R, B, G), the second of itertools.permutations: G's block holds B's and B's holds G's.
    np.testing.assert_array_equal(stacked[2:4, 21:42], inputs[:, 42:63])
    np.testing.assert_array_equal(stacked[2:4, 42:63], inputs[:, 21:42])
    np.testing.assert_array_equal(stacked[2:4, :21], inputs[:, :21])
    # Every order appears once: each colour block of a material goes to each position twice over 6 orders.
    blocks = stacked.reshape(6, 2, 3, 21, 90, 90)[:, 0, :, 0, 0, 10]
    assert len({tuple(row) for row in blocks.tolist()}) == 6
    with pytest.raises(ValueError, match="shape"):
        with_colour_permutations(inputs[:, :62])


@pytest.mark.slow
def test_a_basis_fitted_with_colour_permutations_spans_the_permuted_materials() -> None:
    inputs, masks = coloured_inputs(3)
    permuted = with_colour_permutations(inputs)

    def worst_projection_error(components: np.ndarray, entries: np.ndarray) -> float:
        flat = permuted.reshape(len(permuted), -1)[:, entries].astype(np.float64)
        centred = flat - flat[:3].mean(0)  # a basis codes residuals: the mean is the decoder's business
        b = components.astype(np.float64)
        return float(np.abs(centred - centred @ b.T @ b).max() / np.abs(centred).max())

    plain = fit_shared_basis(inputs, masks, 2)
    both = fit_shared_basis(inputs, masks, 14, colour_permutations=True)
    assert both[0].shape == (14, 63 * 90 * 90) and np.array_equal(both[1], plain[1])
    gram = both[0].astype(np.float64) @ both[0].astype(np.float64).T
    np.testing.assert_allclose(gram, np.eye(14), atol=3e-3)
    # Colours the measured materials lack are in the permuted basis' span, not in the plain one's.
    assert worst_projection_error(*both) < 5e-3
    assert worst_projection_error(*plain) > 0.1
    # 6 colour orders of 3 materials span 5 · 3 − 1 = 14 dimensions, not 17: a 15th vector would be noise.
    assert shared_basis_rank(3, colour_permutations=True) == 14 and shared_basis_rank(3) == 2
    with pytest.raises(ValueError, match=r"\[1, 14\] for 3 materials in 6 colour orders"):
        fit_shared_basis(inputs, masks, 15, colour_permutations=True)


def test_a_permuted_basis_covers_only_entries_valid_in_every_colour() -> None:
    inputs, masks = coloured_inputs(3)
    masks[1, 30, 4, 7] = False  # G, kept slot 9: invalid in one material
    inputs = inputs * masks
    plain = fit_shared_basis(inputs, masks, 2)[1]
    permuted = fit_shared_basis(inputs, masks, 4, colour_permutations=True)[1]
    position = 4 * 90 + 7
    same_place = [c * 21 * 8100 + 9 * 8100 + position for c in range(3)]
    assert [e in set(plain.tolist()) for e in same_place] == [True, False, True]
    assert not set(same_place) & set(permuted.tolist())  # it moves to R and B in other orders
    assert len(permuted) == 63 * 90 * 90 - 3


def test_fit_basis_keeps_a_models_basis_unless_told_to_replace_it(tmp_path, capsys) -> None:
    import shutil

    from brdfcodec.cli.main import main
    from brdfcodec.models.registry import default_model_folder

    folder = tmp_path / "model"
    shutil.copytree(default_model_folder(), folder)
    before = (folder / "basis.safetensors").read_bytes(), (folder / "model.json").read_bytes()
    assert main(["model", "fit-basis", str(folder), "--dataset", str(tmp_path / "absent.h5")]) == 1
    err = capsys.readouterr().err
    assert "already has a shared basis" in err and "--replace" in err and "Traceback" not in err
    assert ((folder / "basis.safetensors").read_bytes(), (folder / "model.json").read_bytes()) == before


@pytest.mark.slow
def test_fit_basis_replace_fits_a_new_basis_and_names_it(analytic_training_set, tmp_path, capsys) -> None:
    import json
    import shutil

    from brdfcodec.cli.main import main
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.models.registry import default_model_folder

    folder = tmp_path / "model"
    shutil.copytree(default_model_folder(), folder)
    original = json.loads((folder / "model.json").read_text())
    old_sha = original["basis_sha256"]
    assert main(["model", "fit-basis", str(folder), "--dataset", str(analytic_training_set), "--replace",
                 "--count", "500"]) == 0
    stored = json.loads((folder / "model.json").read_text())
    info = stored["info"]["basis"]
    # 9 or 10 training materials in 6 colour orders: at most 5N − 1 vectors, and the message says how many.
    assert info["colour_permutations"] is True and info["count"] == 5 * info["materials"] - 1
    printed = capsys.readouterr().out
    assert f"{info['count']} vectors" in printed and "kept" not in printed
    decoder = BrdfDecoder(folder)
    basis = decoder.shared_basis
    assert basis is not None and basis.sha256 == stored["basis_sha256"] != old_sha and basis.count == info["count"]
    # One model, one basis: the new basis replaces the old one, which the model no longer names or holds.
    assert sorted(p.name for p in folder.iterdir() if "basis" in p.name) == ["basis.safetensors"]
    assert "previous_bases" not in stored
    assert decoder.basis_named(old_sha) is None and decoder.basis_named(basis.sha256) is basis
    old = LayeredRecord("old", np.linspace(-1, 1, 8), np.ones(8), basis=BasisLayer(
        old_sha, 0.25, np.arange(-3, 4, dtype=np.int8), 8), compact_sigma=True)
    with pytest.raises(BasisMismatchError, match=old_sha[:12]):
        decoder.decode(old)


@pytest.mark.slow
def test_fit_basis_fits_on_the_materials_the_model_lists_as_trained_on(analytic_training_set, tmp_path) -> None:
    import json
    import shutil

    from brdfcodec.cli.main import main
    from brdfcodec.datasets.hdf5 import BrdfDataset
    from brdfcodec.models.registry import default_model_folder

    folder = tmp_path / "model"
    shutil.copytree(default_model_folder(), folder)
    with BrdfDataset(analytic_training_set) as dataset:
        names = [dataset.names[i] for i in dataset.indices("validation")][:1] + list(dataset.names[:2])
    stored = json.loads((folder / "model.json").read_text())
    stored["info"]["data"]["train"] = names  # a fold's materials, one of them outside the stored training split
    (folder / "model.json").write_text(json.dumps(stored))
    assert main(["model", "fit-basis", str(folder), "--dataset", str(analytic_training_set), "--replace",
                 "--count", "500"]) == 0
    info = json.loads((folder / "model.json").read_text())["info"]["basis"]
    assert info["materials"] == len(set(names)) and info["count"] == 5 * len(set(names)) - 1


def test_the_shipped_model_has_a_basis_and_partial_decoding_matches() -> None:
    from brdfcodec.codec import BrdfDecoder

    decoder = BrdfDecoder()
    basis = decoder.shared_basis
    assert basis is not None and basis.count == 200 and basis.entries.shape == (387378,)
    record = basis_record("m", k=20, sha=basis.sha256)
    full = decoder.decode(record, masked="zero")
    base = decoder.decode(record.base(), masked="zero")
    assert np.abs(full - base).max() > 1e-3  # the layer changes the decode
    part = decoder.decode(record, phi_d_bins=[3, 90], masked="zero")
    np.testing.assert_allclose(part, full[..., [3, 90]], rtol=1e-5, atol=1e-5)
    batched = next(decoder.decode_many([record], masked="zero"))
    # A single layered decode runs the network on one torch thread fewer (the layers take the last core):
    # float32 rounding may differ in the last bits, far inside the spec's rtol of 1e-3.
    np.testing.assert_allclose(batched, full, rtol=1e-5, atol=1e-6)
    with pytest.raises(BasisMismatchError, match=SHA):
        decoder.decode(basis_record("other"))  # made for another basis
    too_long = LayeredRecord("long", record.mu, record.sigma,
                             basis=BasisLayer(basis.sha256, 0.5, np.ones(201, dtype=np.int8)))
    with pytest.raises(BasisError, match="this basis holds 200"):
        decoder.decode(too_long)
    past_the_end = LayeredRecord("past", record.mu, record.sigma,
                                 basis=BasisLayer(basis.sha256, 0.5, np.ones(6, dtype=np.int8), 195))
    with pytest.raises(BasisError, match="vectors 195 to 200, but this basis holds 200"):
        decoder.decode(past_the_end)


def test_a_layer_from_vector_f_sums_vectors_f_on() -> None:
    """``first`` (format 1.3) shifts which vectors the coefficients weigh, in full and partial decoding."""
    from brdfcodec.codec import BrdfDecoder

    decoder = BrdfDecoder()
    basis = decoder.shared_basis
    rng = np.random.default_rng(5)
    q = rng.integers(-127, 128, size=6).astype(np.int8)
    mu, sigma = rng.normal(size=8), np.ones(8)
    shifted = LayeredRecord("f", mu, sigma, basis=BasisLayer(basis.sha256, 0.25, q, 8))
    c = 0.25 * q.astype(np.float32)
    expected = decoder.decode_mapped(mu) + basis.residual(np.concatenate([np.zeros(8, np.float32), c]))
    np.testing.assert_allclose(decoder.mapped_record(shifted), np.clip(expected, 0.0, 5.0), atol=2e-6)
    unshifted = decoder.mapped_record(LayeredRecord("u", mu, sigma, basis=BasisLayer(basis.sha256, 0.25, q)))
    assert np.abs(unshifted - decoder.mapped_record(shifted)).max() > 1e-3
    full = decoder.decode(shifted, masked="zero")
    np.testing.assert_allclose(decoder.decode(shifted, phi_d_bins=[7], masked="zero"), full[..., [7]],
                               rtol=1e-5, atol=1e-5)


def test_first_round_trips_and_is_written_only_when_set() -> None:
    layer = quantise_coefficients(SHA, [3.0, -1.0, 0.5], first=8)
    assert layer.first == 8 and layer.entry() == {"sha256": SHA, "count": 3, "first": 8}
    assert quantise_coefficients(SHA, [1.0]).entry() == {"sha256": SHA, "count": 1}  # a 1.2 reader reads it
    record = LayeredRecord("f", np.zeros(8), np.ones(8), basis=layer, compact_sigma=True)
    parsed = parse_bvae(encode_bvae([record], DECODER))
    assert parsed.header.entries[0].layers["basis"] == {"sha256": SHA, "count": 3, "first": 8}
    back = parsed.records[0]
    assert back.basis.first == 8 and back.basis.q.tolist() == layer.q.tolist()
    for bad in (-1, 4094, True, 2.0):
        with pytest.raises(ValueError, match="first"):
            BasisLayer(SHA, 0.5, np.ones(3, dtype=np.int8), bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(("linear_rank", "k", "first"), [(8, 6, 8), (8, 67, 8), (8, 70, 5), (8, 75, 0), (0, 6, 0)])
def test_the_encoder_skips_the_vectors_its_linear_path_spans(linear_rank: int, k: int, first: int) -> None:
    from brdfcodec.layers.basis import basis_offset

    assert basis_offset(linear_rank, 75, k) == first


@pytest.mark.slow
def test_the_basis_layer_follows_the_decoder_output_it_was_fitted_on(analytic_tables) -> None:
    """Rate control at a small budget spends the bytes on basis coefficients, and they help."""
    from brdfcodec.codec import BrdfEncoder, measure

    brdf = analytic_tables["red-plastic"]
    base = BrdfEncoder(effort=1, latent_dtype="float16")
    base_error = measure(base.encode(brdf, name="m"), base.decoder, brdf).meta["relae"]["mapped"]
    # Unprojected, so that the refit below needs no projection (test_projected_base.py covers projected fits).
    # latent="always": this test is about the basis layer beside a latent (records without one: test_basis_only.py)
    # basis_coding="int8": one byte per coefficient (packed layers: test_packed_basis.py)
    encoder = BrdfEncoder(effort=1, bytes=64, latent_dtype="float16", project_base="never", latent="always",
                          basis_coding="int8")
    record = encoder.encode(brdf, name="m")
    # 64 B cannot hold all 75 coefficients beside a float16 μ, so the base is compact: 8 bytes of μ on the fixed
    # grid (its μ fits ±3.97), and no σ (format 2.2: the encoder leaves it out unless asked).
    assert isinstance(record, LayeredRecord) and record.compact_mu and not record.store_sigma
    assert record.detail is None and not record.shared_sigma
    assert record.fixed_mu_grid and np.abs(record.mu).max() <= 127 / 32
    assert np.array_equal(record.mu * 32, np.rint(record.mu * 32))  # on the grid
    assert record.basis is not None and record.basis.count == 64 - 8 - 2 - 3  # μ 8 bytes, the step 2, the index entry 3
    assert record.basis.first == 8  # the shipped decoder's linear path spans the basis' first 8 vectors
    entry = parse_bvae(encode_bvae([record], encoder.reference, latent_dtype="float16")).header.entries[0]
    assert entry.length == record.meta["rate"]["payload_bytes"] == 61
    assert entry.length + entry.descriptor_bytes == record.meta["rate"]["record_bytes"] == 64
    layered_error = measure(record, encoder.decoder, brdf).meta["relae"]["mapped"]
    assert layered_error < 0.9 * base_error
    # The coefficients are fitted to the quantised μ the record stores: refitting them to it gives the same ones.
    from brdfcodec.codec.refine import fit_basis_coefficients
    from brdfcodec.representation import network_input_from_table

    inputs, masks = network_input_from_table(brdf.values, brdf.mask)
    basis = encoder.decoder.shared_basis
    _, refitted = fit_basis_coefficients(encoder.decoder.network, record.mu[None], inputs[None], masks[None],
                                         basis.vectors(8, record.basis.count), basis.entries, 1,
                                         fit_latent=False)
    assert quantise_coefficients(basis.sha256, refitted[0], 8).q.tolist() == record.basis.q.tolist()
    # the smallest record with int8 coefficients: compact base, 1 coefficient
    tiny = BrdfEncoder(effort=1, bytes=14, basis_coding="int8").encode(brdf, name="t")
    assert tiny.basis.count == 1 and tiny.meta["rate"]["payload_bytes"] == 11
    assert tiny.meta["rate"]["record_bytes"] == 14  # with its index entry: name length, form, count
    no_basis = BrdfEncoder(effort=1, bytes=64, latent_dtype="float16", basis=False).encode(brdf, name="m")
    assert getattr(no_basis, "basis", None) is None


@pytest.mark.slow
def test_an_error_target_takes_the_smallest_candidate_that_meets_it(analytic_tables) -> None:
    from brdfcodec.codec import BrdfEncoder, measure

    brdf = analytic_tables["red-plastic"]
    probe = BrdfEncoder(effort=0, bytes=40, latent_dtype="float16", latent="always")
    record = probe.encode(brdf, name="m")
    reached = measure(record, probe.decoder, brdf).meta["relae"]["mapped"]
    # latent="always": the candidates with a latent (records without one: test_basis_only.py); the ladder's own
    # candidates, without the coded-μ records searched below its choice (test_coded_mu.py)
    encoder = BrdfEncoder(effort=0, max_relae=reached * 1.05, latent_dtype="float16", latent="always",
                          coded_mu_step=0)
    chosen = encoder.encode(brdf, name="m")
    assert measure(chosen, encoder.decoder, brdf).meta["relae"]["mapped"] <= reached * 1.05
    assert isinstance(chosen, LayeredRecord) and chosen.basis is not None and chosen.detail is None
    # a record without a detail layer stores its base compact, as a size budget does: at most 32 coefficients
    assert chosen.compact_mu and not chosen.store_sigma and chosen.fixed_mu_grid
    # in the bytes of at most 32 int8 coefficients and their step (packed, format 2.3, or coded, format 2.4, the
    # default --basis-coding auto's choice: more coefficients)
    assert chosen.meta["rate"]["payload_bytes"] == 8 + chosen.basis.nbytes <= 42
    assert chosen.basis.top or chosen.basis.prior is not None
    loose = BrdfEncoder(effort=0, max_relae=1.0, latent_dtype="float16", latent="always",
                        coded_mu_step=0).encode(brdf, name="m")
    assert loose.compact_mu and loose.basis.count >= 4 and loose.meta["rate"]["payload_bytes"] == 8 + loose.basis.nbytes
    assert loose.basis.nbytes <= 2 + 4  # the smallest candidate: the bytes of 4 int8 coefficients
    # with the default coded-μ candidates: a record no larger, that meets the target as well (strictly smaller
    # where a coded-μ record meets it: test_coded_mu.py's error-target test)
    default = BrdfEncoder(effort=0, max_relae=reached * 1.05, latent_dtype="float16", latent="always")
    smaller = default.encode(brdf, name="m")
    assert smaller.meta["rate"]["record_bytes"] <= chosen.meta["rate"]["record_bytes"]
    assert measure(smaller, default.decoder, brdf).meta["relae"]["mapped"] <= reached * 1.05


def test_an_error_target_tries_candidates_from_small_to_large() -> None:
    from brdfcodec.codec.rate import DETAIL_BASIS_COUNT, STEP_LADDER, error_target_sequence

    sequence = error_target_sequence(75)
    assert sequence[:5] == [(True, 4, None), (True, 8, None), (True, 16, None), (True, 32, None), (True, 75, None)]
    assert sequence[5:] == [(False, DETAIL_BASIS_COUNT, s) for s in STEP_LADDER]  # a detail layer: at most 32
    assert error_target_sequence(20)[:4] == [(True, 4, None), (True, 8, None), (True, 16, None), (True, 20, None)]
    assert error_target_sequence(20)[4:] == [(False, 20, s) for s in STEP_LADDER]
    assert error_target_sequence(0) == [(False, 0, None), *((False, 0, s) for s in STEP_LADDER)]


@pytest.mark.slow
def test_cli_bytes_writes_the_basis_layer(red_plastic_file, tmp_path, capsys) -> None:
    from brdfcodec.cli.main import main

    out = tmp_path / "r.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(out), "--bytes", "64", "--float16",
                 "--provenance", "--latent", "always", "--basis-coding", "int8"]) == 0  # no latent: test_basis_only.py
    entry = parse_bvae(out.read_bytes()).header.entries[0]
    # 64 B beyond the name: 61 B of payload (9 of compact base, 2 of step, 50 coefficients) and 3 of index entry
    assert entry.kind == "layered" and entry.length == 61 and entry.layers["basis"]["count"] == 51
    assert entry.length + entry.descriptor_bytes == 64
    assert entry.meta["relae"]["mapped"] > 0  # measured on the record that was written
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    shown = capsys.readouterr().out
    assert "μ int8 grid, σ none, basis 51 (vectors 9–59)" in shown
    assert "61 B payload, 64 B with its index entry" in shown
    projected = entry.layers["basis"].get("project") == 50  # auto: chosen per material
    assert ("base projected on 50" in shown) == projected
    smallest = tmp_path / "s.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(smallest), "--bytes", "14", "--latent", "always",
                 "--basis-coding", "int8"]) == 0
    capsys.readouterr()
    assert main(["info", str(smallest)]) == 0
    shown = capsys.readouterr().out
    assert "μ int8 grid, σ none, basis 1 (vector 9)" in shown and "11 B payload, 14 B with its index" in shown
    # below the smallest packed layered record: the compact base alone, no layer (10 B with its index entry) ...
    alone = tmp_path / "alone.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(alone), "--bytes", "13", "--latent", "always",
                 "--basis-coding", "packed"]) == 0
    capsys.readouterr()
    assert main(["info", str(alone)]) == 0
    assert "μ int8 grid, σ none; 8 B payload, 10 B with its index entry" in capsys.readouterr().out
    # ... where, by default, μ coded in a coded layer's stream (format 2.5) leaves room for coefficients
    coded = tmp_path / "coded.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(coded), "--bytes", "13", "--latent", "always"]) == 0
    capsys.readouterr()
    assert main(["info", str(coded)]) == 0
    assert "μ coded in the basis layer, grid 2^-3, σ none, basis" in capsys.readouterr().out
    assert main(["compress", str(red_plastic_file), "-o", str(tmp_path / "t.bvae"), "--bytes", "9",
                 "--latent", "always"]) != 0
    assert "--bytes 9 is below the smallest record" in capsys.readouterr().err
    assert not (tmp_path / "t.bvae").exists()


@pytest.mark.parametrize("step", [1e-4, 1.0, 60000.0])
def test_extreme_basis_coefficients_decode_finite_and_in_range(step: float) -> None:
    """The largest and smallest steps a float16 holds, all coefficients at ±127: clamped, finite, ≥ 0."""
    from brdfcodec.codec import BrdfDecoder

    decoder = BrdfDecoder()
    sha = decoder.shared_basis.sha256
    q = np.where(np.arange(75) % 2 == 0, 127, -127).astype(np.int8)
    for mu in (np.zeros(8), np.full(8, 6.0), np.full(8, -6.0)):
        record = LayeredRecord("x", mu, np.ones(8), basis=BasisLayer(sha, float(np.float16(step)), q))
        table = decoder.decode(record, masked="zero")
        assert np.isfinite(table).all() and table.min() >= 0.0


@pytest.mark.slow
def test_float16_decoding_of_a_basis_record_stays_close(analytic_tables) -> None:
    import torch

    from brdfcodec.codec import BrdfDecoder, BrdfEncoder
    from brdfcodec.representation.metrics import relae_mapped

    brdf = analytic_tables["chrome"]  # a hard material: a sharp, bright lobe
    record = BrdfEncoder(effort=0, bytes=128, latent_dtype="float16").encode(brdf, name="chrome")
    assert isinstance(record, LayeredRecord) and record.basis is not None
    full = BrdfDecoder().decode(record, masked="keep").astype(np.float64)
    half = BrdfDecoder(dtype=torch.float16).decode(record, masked="keep").astype(np.float64)
    assert np.isfinite(half).all()
    assert relae_mapped(full, half, brdf.mask).overall < 0.01  # the bound spec §6 states for the base


@pytest.mark.parametrize("name", ["chrome", "black-obsidian"])
@pytest.mark.slow
def test_extreme_materials_layered_within_budget(analytic_tables, name: str) -> None:
    from brdfcodec.codec import BrdfEncoder, measure

    brdf = analytic_tables[name]
    base = BrdfEncoder(effort=1, latent_dtype="float16")
    base_error = measure(base.encode(brdf, name=name), base.decoder, brdf).meta["relae"]["mapped"]
    encoder = BrdfEncoder(effort=1, bytes=128, latent_dtype="float16")
    record = measure(encoder.encode(brdf, name=name), encoder.decoder, brdf)
    assert record.meta["rate"]["payload_bytes"] <= 128
    assert np.isfinite(record.meta["relae"]["mapped"]) and record.meta["relae"]["mapped"] <= base_error + 1e-9


@pytest.mark.slow
def test_coefficients_fitted_to_a_fixed_code_leave_it_and_lower_the_error(analytic_tables) -> None:
    """``fit_latent=False`` (a compact μ): the code is kept as given, and the Adam steps on the coefficients never
    end above the least-squares start."""
    from brdfcodec.codec import BrdfDecoder, BrdfEncoder
    from brdfcodec.codec.refine import fit_basis_coefficients
    from brdfcodec.conventions import MAPPED_MAX
    from brdfcodec.representation import network_input_from_table

    decoder = BrdfDecoder()
    basis = decoder.shared_basis
    brdf = analytic_tables["red-plastic"]
    inputs, masks = network_input_from_table(brdf.values, brdf.mask)
    code = BrdfEncoder(effort=0).encode(brdf).mu + np.float32(0.05)  # off the encoder's own answer
    components = basis.vectors(8, 20)
    codes, fitted = fit_basis_coefficients(decoder.network, code[None], inputs[None], masks[None], components,
                                           basis.entries, 1, fit_latent=False)
    np.testing.assert_array_equal(codes[0], code)
    base = decoder.decode_mapped(code)
    start = basis._float32[8:28] @ ((inputs - base) * masks).reshape(-1)[basis.entries]  # the projection

    def l1(c: np.ndarray) -> float:
        mapped = np.clip(base + basis.residual(c, 8), 0.0, MAPPED_MAX)
        return float((np.abs(mapped - inputs) * masks).sum())

    assert l1(fitted[0]) < l1(start)


@pytest.mark.slow
def test_a_fit_minimises_the_error_it_is_given(analytic_tables) -> None:
    """``error=``: the fit keeps, of the pairs it visits, the best under the objective it was given (here L2),
    which need not be the default L1's best."""
    import torch

    from brdfcodec.codec import BrdfDecoder, BrdfEncoder
    from brdfcodec.codec.refine import fit_basis_coefficients
    from brdfcodec.conventions import MAPPED_MAX
    from brdfcodec.representation import network_input_from_table

    decoder = BrdfDecoder()
    basis = decoder.shared_basis
    brdf = analytic_tables["red-plastic"]
    inputs, masks = network_input_from_table(brdf.values, brdf.mask)
    code = BrdfEncoder(effort=0).encode(brdf).mu
    components = basis.vectors(8, 12)

    def squared(decoded: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
        return ((decoded - target) * weight).square().sum(1)

    def fitted(**kwargs) -> tuple[np.ndarray, np.ndarray]:
        codes, coefficients = fit_basis_coefficients(decoder.network, code[None], inputs[None], masks[None],
                                                     components, basis.entries, 1, **kwargs)
        return codes[0], coefficients[0]

    def errors(z: np.ndarray, c: np.ndarray) -> tuple[float, float]:
        mapped = np.clip(decoder.decode_mapped(z), 0.0, MAPPED_MAX) + basis.residual(c, 8)
        difference = (mapped - inputs) * masks
        return float(np.abs(difference).sum()), float(np.square(difference).sum())

    l1_fit, l2_fit = errors(*fitted()), errors(*fitted(error=squared))
    assert l2_fit[1] <= l1_fit[1] * (1 + 1e-4)  # the L2 objective's own measure
    assert l1_fit[0] <= l2_fit[0] * (1 + 1e-4)  # and the default's
    assert l1_fit != l2_fit


@pytest.mark.slow
def test_a_factorised_basis_file_expands_to_the_dense_basis_it_stands_for(tmp_path) -> None:
    from brdfcodec.layers.basis import fit_factorised_basis, write_factorised_basis
    from brdfcodec.layers.colour_orders_pca import COLOUR_VECTORS

    x, m = coloured_inputs(4)
    factorised = fit_factorised_basis(x, m, 12)
    components, entries = factorised.expand()
    dense, dense_entries = fit_shared_basis(x, m, 12, colour_permutations=True)
    np.testing.assert_array_equal(components, dense)
    np.testing.assert_array_equal(entries, dense_entries)
    # The spec's rule (spec/model.md 1.4), written out: vector k is w_c · u_e in binary32, colour-major; the
    # dense layout rounds it to binary16.
    k = 5
    w = COLOUR_VECTORS.astype(np.float32)[factorised.colours[k]]
    u = factorised.factors[factorised.factor_of[k]].astype(np.float32)
    exact = np.concatenate([w[c] * u for c in range(3)])
    np.testing.assert_array_equal(components[k], exact.astype(np.float16))
    assert len(factorised.factors) < 12  # chroma pairs share a factor
    path = tmp_path / "basis.safetensors"
    sha = write_factorised_basis(path, factorised)
    loaded = load_shared_basis(path, sha)
    assert loaded.components is None and loaded.factorised is not None  # never expanded when read
    np.testing.assert_array_equal(loaded.vectors(k, 1)[0], exact)
    np.testing.assert_array_equal(loaded.entries, dense_entries)
    np.testing.assert_allclose(loaded.vectors(0, 12), dense, atol=2e-3)
    assert path.stat().st_size < 0.5 * dense.nbytes
    from safetensors.numpy import save_file

    from brdfcodec.io.hashing import sha256_of_file

    good = {"factors": factorised.factors, "colours": factorised.colours, "factor_of": factorised.factor_of,
            "colour_entries": factorised.colour_entries}
    bad = [
        ({"colours": factorised.colours + 3}, "'colours' must be 0"),
        ({"factor_of": factorised.factor_of + 40}, "'factor_of' must name factor rows"),
        ({"colour_entries": factorised.colour_entries[::-1].copy()}, "strictly increasing"),
        ({"factors": factorised.factors.astype(np.float32)}, "float16"),
        ({"factors": np.full_like(factorised.factors, np.inf)}, "non-finite"),
        ({"colours": factorised.colours[:-1]}, "one per vector"),
        # 4097 vectors are refused before the expansion would allocate them
        ({"colours": np.zeros(4097, np.int64), "factor_of": np.zeros(4097, np.int64)},
         "'colours' lists 4097 vectors"),
    ]
    for change, message in bad:  # a hostile file is refused when read, whatever wrote it
        broken = tmp_path / "bad.safetensors"
        save_file({**good, **change}, str(broken))
        with pytest.raises(BasisError, match=message):
            load_shared_basis(broken, sha256_of_file(broken))
    save_file({k: v for k, v in good.items() if k != "factor_of"}, str(broken))
    with pytest.raises(BasisError, match="factor_of"):
        load_shared_basis(broken, sha256_of_file(broken))


def test_the_shipped_model_holds_one_basis_and_manifests_ignore_previous_bases(tmp_path) -> None:
    import json
    import shutil

    from brdfcodec.models.manifest import load_manifest
    from brdfcodec.models.registry import default_model_folder

    shipped = default_model_folder()
    assert [p.name for p in shipped.iterdir() if p.suffix == ".safetensors" and "basis" in p.name] == [
        "basis.safetensors"]
    assert "previous_bases" not in json.loads((shipped / "model.json").read_text())
    folder = tmp_path / "model"
    shutil.copytree(shipped, folder)
    stored = json.loads((folder / "model.json").read_text())
    (folder / "model.json").write_text(json.dumps({**stored, "previous_bases": {"ab" * 32: "../x"}}))
    assert not hasattr(load_manifest(folder), "previous_bases")  # a field of model spec 1.3-1.4, ignored


def test_sums_on_the_factors_equal_sums_over_the_expanded_vectors() -> None:
    """The decoder's kernels on a factorised basis (fold + combine, dots, values at entries, partial channels) give
    what the dense binary32 vectors give, with unused leading and trailing factors skipped correctly."""
    from brdfcodec.layers.basis import fit_factorised_basis

    x, m = coloured_inputs(4)
    factorised = fit_factorised_basis(x, m, 14)
    entries = factorised.entries()
    factored = SharedBasis(None, entries, "ab" * 32, factorised)
    dense = factored.vectors(0, 14).astype(np.float64)
    other = SharedBasis(factored.vectors(0, 14).astype(np.float16), entries, "cd" * 32)
    rng = np.random.default_rng(3)
    for first, k in ((0, 14), (3, 7), (13, 1), (5, 2)):
        c = rng.normal(size=k).astype(np.float32)
        want = c.astype(np.float64) @ dense[first : first + k]
        np.testing.assert_allclose(factored.weighted_sum(c, first), want, atol=1e-5)
        np.testing.assert_allclose(other.weighted_sum(c, first), want, atol=2e-3)
        np.testing.assert_allclose(factored.residual(c, first).reshape(-1)[entries], want, atol=1e-5)
        assert np.count_nonzero(factored.residual(c, first)) == np.count_nonzero(want)
        channels = [0, 20, 21, 40, 62]
        full = factored.residual(c, first)
        np.testing.assert_allclose(factored.residual_channels(c, channels, first), full[channels], atol=1e-6)
        np.testing.assert_allclose(other.residual_channels(c, channels, first), other.residual(c, first)[channels],
                                   atol=1e-6)
    y = rng.normal(size=(2, len(entries))).astype(np.float32)
    for count in (1, 6, 14):
        np.testing.assert_allclose(factored.dots(y, count), y.astype(np.float64) @ dense[:count].T, atol=1e-4)
        np.testing.assert_allclose(factored.dots(y[0], count), y[0].astype(np.float64) @ dense[:count].T, atol=1e-4)
    where = np.array([0, 7, len(entries) // 3 + 5, len(entries) - 1])
    np.testing.assert_array_equal(factored.vector_values(9, where), factored.vectors(0, 9)[:, where])
    np.testing.assert_allclose(other.vector_values(9, where), factored.vectors(0, 9)[:, where], atol=2e-3)
    centre = rng.normal(size=len(entries)).astype(np.float32)
    a = (y[0] - centre).astype(np.float64) @ dense[:6].T
    np.testing.assert_allclose(factored.project(y[0], centre, 6), centre + a @ dense[:6], atol=1e-4)
    np.testing.assert_allclose(factored.project(y, centre, 6)[0], centre + a @ dense[:6], atol=1e-4)
    with pytest.raises(BasisError, match="holds 14"):
        factored.weighted_sum(np.ones(3, np.float32), 12)
    with pytest.raises(ValueError, match="dense .* or factorised"):
        SharedBasis(None, entries, "ab" * 32)
