"""Issue 14, format 1.6: the projected base (``layers.basis.project``, spec §4.5)."""

from __future__ import annotations

import numpy as np
import pytest
from bvae_bytes import bytes_writer

from brdfcodec.errors import BvaeFormatError
from brdfcodec.format.bvae import DecoderReference, encode_bvae, parse_bvae
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.layers.basis import BasisError, BasisLayer, SharedBasis, quantise_coefficients

DECODER = DecoderReference("ab" * 32, "test-decoder")
SHA = "cd" * 32


def small_basis(k: int = 6, entries: int = 40) -> SharedBasis:
    rng = np.random.default_rng(11)
    q, _ = np.linalg.qr(rng.normal(size=(entries, k)))
    return SharedBasis(q.T.astype(np.float16), np.arange(3, 3 + entries, dtype=np.int64), SHA)


def test_projection_is_the_orthogonal_projection_around_the_centre() -> None:
    basis = small_basis()
    rng = np.random.default_rng(12)
    y, m = rng.normal(size=40), rng.normal(size=40)
    v = basis.vectors(0, 4).astype(np.float64)
    expected = m + (y - m) @ v.T @ v
    np.testing.assert_allclose(basis.project(y, m, 4), expected, rtol=1e-5, atol=1e-5)
    once = basis.project(y, m, 4)
    np.testing.assert_allclose(basis.project(once, m, 4), once, atol=1e-3)  # idempotent up to float16 vectors
    inside = m + 2.0 * v[1] - 0.5 * v[3]
    np.testing.assert_allclose(basis.project(inside, m, 4), inside, atol=1e-3)  # the span is kept
    batch = basis.project(np.stack([y, 2 * y]), m, 4)
    np.testing.assert_allclose(batch[1], basis.project(2 * y, m, 4), rtol=1e-5, atol=1e-6)
    with pytest.raises(BasisError, match="holds 6"):
        basis.project(y, m, 7)


def test_project_round_trips_and_is_written_only_when_set() -> None:
    layer = quantise_coefficients(SHA, [3.0, -1.0, 0.5], first=8, project=50)
    assert layer.entry() == {"sha256": SHA, "count": 3, "first": 8, "project": 50}
    assert "project" not in quantise_coefficients(SHA, [1.0], first=8).entry()  # a 1.5 reader reads it
    record = LayeredRecord("p", np.zeros(8), np.ones(8), basis=layer, compact_sigma=True)
    parsed = parse_bvae(encode_bvae([record], DECODER))
    assert (parsed.header.major, parsed.header.minor) == (2, 1)
    assert parsed.header.entries[0].layers["basis"]["project"] == 50
    assert parsed.records[0].basis.project == 50
    for bad in (-1, 4097, True, 2.0):
        with pytest.raises(ValueError, match="projection"):
            BasisLayer(SHA, 0.5, np.ones(3, dtype=np.int8), 0, bad)  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", [4097, 5000, 2**27])
def test_a_project_that_is_not_a_vector_count_is_malformed(bad: int) -> None:
    """A form's ``project`` is a varint (0: not projected); past the 4096 vectors a basis may hold it is malformed.
    Written by hand: the writer refuses it (BasisLayer)."""
    payload = np.zeros(8, dtype="<f4").tobytes() + bytes(8) + np.float16(0.5).tobytes() + bytes([3, 1])
    form = bytes_writer.layered_form(0, 1, basis=(0, bad))
    stored = bytes_writer.header([form], [bytes_writer.descriptor("p", 0, count=2)], payload, dim=8, basis=SHA)
    with pytest.raises(BvaeFormatError, match="project"):
        parse_bvae(bytes_writer.assemble(stored, payload, flags=2))
    with pytest.raises(ValueError, match="projection"):
        BasisLayer(SHA, 0.5, np.ones(2, dtype=np.int8), 0, bad)


def test_the_shipped_decoder_projects_the_base_as_the_spec_says() -> None:
    from brdfcodec.codec import BrdfDecoder

    decoder = BrdfDecoder()
    basis = decoder.shared_basis
    rng = np.random.default_rng(13)
    mu = rng.normal(size=8).astype(np.float32)
    q = rng.integers(-127, 128, size=5).astype(np.int8)
    projected = LayeredRecord("p", mu, np.ones(8), basis=BasisLayer(basis.sha256, 0.25, q, 8, 50))
    plain = LayeredRecord("u", mu, np.ones(8), basis=BasisLayer(basis.sha256, 0.25, q, 8))
    # The spec, written out: the centre is the decoder's float16 linear-path mean at the basis' entries.
    network = decoder.network
    index = network.valid_index.numpy()
    centre = network.basis_mean.float().numpy()[np.searchsorted(index, basis.entries)]
    base = decoder.decode_mapped(mu).reshape(-1)
    v = basis.vectors(0, 50).astype(np.float64)
    y = base[basis.entries].astype(np.float64)
    base[basis.entries] = centre + (y - centre) @ v.T @ v
    expected = base.reshape(63, 90, 90) + basis.residual(0.25 * q.astype(np.float32), 8)
    got = decoder.mapped_record(projected)
    np.testing.assert_allclose(got, np.clip(expected, 0.0, 5.0), atol=5e-5)
    assert np.abs(got - decoder.mapped_record(plain)).max() > 1e-2  # the projection changes the decode
    full = decoder.decode(projected, masked="zero")
    # the same values up to float32 summation order (2 ulp at the grazing values near 1e6)
    np.testing.assert_allclose(decoder.decode(projected, phi_d_bins=[7, 90], masked="zero"), full[..., [7, 90]],
                               rtol=3e-6, atol=1e-6)
    batched = next(decoder.decode_many([projected], masked="zero"))
    np.testing.assert_allclose(batched, full, rtol=1e-5, atol=1e-6)
    assert np.isfinite(full).all()
    fewer = LayeredRecord("p25", mu, np.ones(8), basis=BasisLayer(basis.sha256, 0.25, q, 8, 25))
    decoder.mapped_record(fewer)
    # One plan per basis, whatever the records' P: a file's counts cannot multiply the decoder's memory.
    assert list(decoder.__dict__["_projection_plans"]) == [basis.sha256]
    # The earlier 75-vector basis the shipped one extends (spec/model.md §5): the same plan, its own bound.
    assert decoder.manifest is not None
    for sha, size in decoder.manifest.basis_prefixes.items():
        earlier = LayeredRecord("e", mu, np.ones(8), basis=BasisLayer(sha, 0.25, q, 8, 50))
        assert np.array_equal(decoder.mapped_record(earlier), decoder.mapped_record(projected))
        assert list(decoder.__dict__["_projection_plans"]) == [basis.sha256]
        past = LayeredRecord("t", mu, np.ones(8), basis=BasisLayer(sha, 0.25, q, 8, size + 1))
        with pytest.raises(BasisError, match=f"projects its base on {size + 1} basis vectors, but this model's "
                                             f"shared basis holds {size}"):
            decoder.decode(past)
    too_many = LayeredRecord("t", mu, np.ones(8), basis=BasisLayer(basis.sha256, 0.25, q, 8, basis.count + 1))
    with pytest.raises(BasisError, match=f"projects its base on {basis.count + 1} basis vectors, but this model's "
                                         f"shared basis holds {basis.count}"):
        decoder.decode(too_many)


def test_a_decoder_without_a_linear_path_refuses_a_projected_base() -> None:
    import dataclasses

    import torch

    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.models.network import Decoder

    shipped = BrdfDecoder()
    config = dataclasses.replace(shipped.network.config, linear_basis=False)
    decoder = BrdfDecoder.from_network(Decoder(config).eval())
    decoder.__dict__["shared_basis"] = shipped.shared_basis
    basis = shipped.shared_basis
    record = LayeredRecord("p", np.zeros(8), np.ones(8), basis=BasisLayer(basis.sha256, 0.25, np.ones(3, np.int8),
                                                                          8, 50))
    with torch.no_grad(), pytest.raises(BasisError, match="linear-path mean"):
        decoder.mapped_record(record)


@pytest.mark.parametrize("budget", [32, 64])
@pytest.mark.slow
def test_the_encoder_projects_where_that_lowers_the_error(analytic_tables, budget: int) -> None:
    """``never`` and ``always`` do as they say; ``auto`` (the default) writes whichever of the two has the lower
    kept-slice error on the material."""
    from brdfcodec.codec import BrdfEncoder
    from brdfcodec.codec.encoding import PROJECTED_BASE_VECTORS, EncodeOptions
    from brdfcodec.representation import network_input_from_table

    table = analytic_tables["red-plastic"]
    inputs, masks = network_input_from_table(table.values, table.mask)
    records, errors = {}, {}
    for way in ("never", "always", "auto"):
        # latent="always": projection concerns records with a latent (those without one: test_basis_only.py)
        encoder = BrdfEncoder(bytes=budget, latent_dtype="float16", project_base=way, latent="always")
        records[way] = encoder.encode(table, name="m")
        errors[way] = float((np.abs(encoder.decoder.mapped_record(records[way]) - inputs) * masks).sum())
        assert records[way].meta["rate"]["payload_bytes"] <= budget
    assert records["never"].basis.project == 0 and records["always"].basis.project == PROJECTED_BASE_VECTORS == 50
    assert errors["never"] != errors["always"]
    best = min(("never", "always"), key=errors.__getitem__)
    assert records["auto"].basis.project == records[best].basis.project
    assert errors["auto"] == pytest.approx(errors[best], rel=1e-5)
    assert EncodeOptions().project_base == "auto"
    assert EncodeOptions(project_base=True).project_base == "always"
    assert EncodeOptions(project_base=False).project_base == "never"
    with pytest.raises(ValueError, match="project_base must be one of"):
        EncodeOptions(project_base="sometimes")  # type: ignore[arg-type]


@pytest.mark.slow
def test_auto_leaves_records_with_a_detail_layer_unprojected(analytic_tables) -> None:
    """A projected base under a detail layer decodes past the 1.5x a layered decode may take, so ``auto`` keeps
    the projection to records without one; ``always`` still projects them."""
    from brdfcodec.codec import BrdfEncoder

    table = analytic_tables["red-plastic"]
    # 4 KB: a detail layer (at 2 KB the 200-vector basis alone is the lower error)
    auto = BrdfEncoder(effort=0, bytes=4096).encode(table, name="m")
    always = BrdfEncoder(effort=0, bytes=4096, project_base="always").encode(table, name="m")
    assert auto.detail is not None and always.detail is not None
    assert auto.basis.project == 0 and always.basis.project == 50


@pytest.mark.parametrize("compact", [None, "int8-fixed"])
@pytest.mark.slow
def test_the_encoders_fit_is_the_decode_of_the_record_it_writes(analytic_tables, compact: str | None) -> None:
    """Rate control measures, and the detail layer codes, what the encoder's basis fit returns: it must be what
    the decoder makes of the written record, projection included."""
    from brdfcodec.codec import BrdfEncoder
    from brdfcodec.codec.encoding import EncodeOptions, _basis_fit
    from brdfcodec.format.bvae import LatentRecord
    from brdfcodec.representation import network_input_from_table

    encoder = BrdfEncoder()
    decoder = encoder.decoder
    table = analytic_tables["red-plastic"]
    inputs, masks = network_input_from_table(table.values, table.mask)
    mu = encoder.encode(table, name="m").mu
    base = LatentRecord("m", mu, np.full(8, 0.01, np.float32), {})
    fit = _basis_fit(decoder, decoder.shared_basis, base, inputs, masks, EncodeOptions(effort=0, project_base=True))
    record, layer, mapped = fit(21, compact, False)
    assert layer.project == 50
    written = LayeredRecord("m", record.mu, record.sigma, basis=layer, compact_mu=compact is not None,
                            shared_sigma=compact is not None, fixed_mu_grid=compact is not None,
                            compact_sigma=compact is None)
    np.testing.assert_allclose(decoder.mapped_record(written), np.clip(mapped, 0.0, 5.0), atol=1e-5)


@pytest.mark.slow
def test_cli_project_base(red_plastic_file, tmp_path, capsys) -> None:
    from brdfcodec.cli.main import main

    out = tmp_path / "p.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(out), "--bytes", "64", "--project-base",
                 "--latent", "always"]) == 0
    entry = parse_bvae(out.read_bytes()).header.entries[0]
    assert entry.layers["basis"]["project"] == 50 and entry.length <= 64
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    assert "base projected on 50" in capsys.readouterr().out
    never = tmp_path / "n.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(never), "--bytes", "64", "--project-base", "never",
                 "--latent", "always"]) == 0
    assert parse_bvae(never.read_bytes()).header.entries[0].layers["basis"].get("project") is None
    lonely = tmp_path / "l.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(lonely), "--project-base"]) != 0
    assert "--project-base applies to records with a basis layer" in capsys.readouterr().err
    assert not lonely.exists()


def test_the_joint_fit_codes_the_residual_of_the_projected_base(analytic_tables) -> None:
    """At effort 0 the coefficients are the projection of what the *projected* base leaves (spec §4.5)."""
    from brdfcodec.codec import BrdfEncoder
    from brdfcodec.codec.refine import fit_basis_coefficients
    from brdfcodec.representation import network_input_from_table

    encoder = BrdfEncoder(effort=0)
    decoder = encoder.decoder
    basis = decoder.shared_basis
    table = analytic_tables["red-plastic"]
    inputs, masks = network_input_from_table(table.values, table.mask)
    code = encoder.encode(table, name="m").mu
    # Vectors past the 50 of the projection: there the projected base is the centre's, not the decoder's output.
    vectors = basis.vectors(50, 21).astype(np.float32)
    projection = (basis.vectors(0, 50), decoder.projection_centre)
    def l2(decoded, target, weight):  # least squares: the projection is the best start, never the fallback
        return (((decoded - target) * weight) ** 2).sum(1)

    _, c = fit_basis_coefficients(decoder.network, code[None], inputs[None], masks[None], vectors, basis.entries, 0,
                                  fit_latent=False, projection=projection, error=l2)
    base = decoder.decode_mapped(code).reshape(-1)
    base[basis.entries] = basis.project(base[basis.entries], decoder.projection_centre, 50)
    residual = ((inputs.reshape(-1) - base) * masks.reshape(-1))[basis.entries]
    assert np.abs(c[0]).max() > 0.1  # the coefficients, not the "no coefficients" fallback
    np.testing.assert_allclose(c[0], vectors @ residual, rtol=1e-3, atol=1e-3)
    _, unprojected = fit_basis_coefficients(decoder.network, code[None], inputs[None], masks[None], vectors,
                                            basis.entries, 0, fit_latent=False, error=l2)
    assert np.abs(unprojected[0] - c[0]).max() > 1e-2


@pytest.mark.slow
def test_a_projected_record_with_a_detail_layer_decodes_as_the_spec_says(analytic_tables) -> None:
    """The fast projected decode (dot products through the network's last layer, one pass over the vectors,
    the detail layer beside the network) against the spec's sum written out."""
    from brdfcodec.codec import BrdfEncoder
    from brdfcodec.layers.detail import decode_detail

    encoder = BrdfEncoder(effort=0, bytes=4096, project_base=True)
    decoder = encoder.decoder
    record = encoder.encode(analytic_tables["gold"], name="g")
    assert record.basis is not None and record.basis.project == 50 and record.detail is not None
    expected = decoder.decode_mapped(record.mu)
    decoder.project_base(record, expected)
    expected += decoder.shared_basis.residual(record.basis.coefficients(), record.basis.first)
    expected += decode_detail(record.detail).reshape(expected.shape)
    np.testing.assert_allclose(decoder.mapped_record(record), np.clip(expected, 0.0, 5.0), atol=5e-5)
