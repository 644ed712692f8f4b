"""Format 2.1: layered records without a latent (basis-only records, ``spec/bvae-format.md`` §4.6).

The format (round trip, sizes, the malformed forms), the decode (the decoder's linear-path mean plus the basis
layer, clamped, computed here from ``decoder.safetensors`` itself), rate control (picked where it is better,
never worse than ``latent="always"``), the edits that refuse such records, ``bvae info``, ``bvae compress
--latent`` and the studio.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bvae_bytes import bytes_writer

from brdfcodec.conventions import MAPPED_MAX, NETWORK_INPUT_SHAPE
from brdfcodec.errors import BasisError, BvaeFormatError, NoLatentError, RateTargetError
from brdfcodec.format.bvae import DecoderReference, LatentRecord, encode_bvae, parse_bvae, record_size
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.layers.basis import BasisLayer, quantise_coefficients
from brdfcodec.layers.detail import encode_detail

DECODER = DecoderReference("ab" * 32, "test-decoder")
SHA = "cd" * 32


def without_latent(name: str = "plain-pca", k: int = 5, *, detail: bool = False, sha: str = SHA,
                   first: float = 40.0) -> LayeredRecord:
    layer = quantise_coefficients(sha, np.r_[first, np.linspace(20.0, -3.0, k - 1)])
    residual = None
    if detail:  # a smooth residual: a few DCT coefficients
        field = np.zeros(NETWORK_INPUT_SHAPE, dtype=np.float32)
        field[:21] = np.linspace(-0.3, 0.3, 90, dtype=np.float32)
        residual = encode_detail(field, 0.05)
    return LayeredRecord.without_latent(name, 8, layer, detail=residual)


def same_layer(a: BasisLayer | None, b: BasisLayer | None) -> bool:
    assert a is not None and b is not None
    return (a.sha256, a.step, a.q.tolist(), a.first, a.project) == (b.sha256, b.step, b.q.tolist(), b.first, b.project)


# --------------------------------------------------------------------------- the format


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_records_without_a_latent_round_trip_beside_others(dtype: str) -> None:
    plain = LatentRecord("plain", np.zeros(8), np.ones(8))
    only, with_detail = without_latent(), without_latent("with-detail", 3, detail=True)
    parsed = parse_bvae(encode_bvae([plain, only, with_detail], DECODER, latent_dtype=dtype))  # type: ignore[arg-type]
    assert (parsed.header.major, parsed.header.minor) == (2, 1)
    entry = parsed.header.entry("plain-pca")
    assert entry.layers == {"mu": "none", "sigma": "none", "basis": {"sha256": SHA, "count": 5}}
    # The payload is the basis layer alone (step and k bytes), the descriptor 3 bytes: k + 5 beyond the name.
    assert entry.length == 2 + 5 and entry.descriptor_bytes == 3 == record_size(only) - entry.length
    assert parsed.header.entry("with-detail").length == 2 + 3 + with_detail.detail.nbytes  # type: ignore[union-attr]
    for name, written in (("plain-pca", only), ("with-detail", with_detail)):
        back = parsed.record(name)
        assert isinstance(back, LayeredRecord) and not back.has_latent and back.mu_storage == "none"
        assert back.latent_dim == 8 and np.isnan(back.mu).all() and np.isnan(back.sigma).all()
        assert same_layer(back.basis, written.basis) and back.detail == written.detail
    assert getattr(parsed.record("plain"), "has_latent", True)  # other records are as before


def test_a_record_without_a_latent_needs_an_unprojected_basis_layer() -> None:
    with pytest.raises(ValueError, match="project"):
        LayeredRecord.without_latent("p", 8, BasisLayer(SHA, 0.25, np.ones(3, np.int8), 0, 50))
    with pytest.raises(ValueError, match="needs a basis layer"):
        LayeredRecord("d", np.zeros(8), np.ones(8), detail=without_latent(detail=True).detail, has_latent=False)
    with pytest.raises(ValueError, match="stores no mu or sigma"):
        LayeredRecord("c", np.zeros(8), np.ones(8), basis=without_latent().basis, has_latent=False,
                      shared_sigma=True)
    with pytest.raises(NoLatentError, match="plain-pca"):
        without_latent().base()


def _file(form: bytes, payload: bytes, *, count: int | None = 3, basis: str | None = SHA) -> bytes:
    w = bytes_writer
    stored = w.header([form], [w.descriptor("b", 0, count=count)], payload, dim=8, basis=basis)
    return w.assemble(stored, payload, flags=2 if basis else 0)


@pytest.mark.parametrize(("form", "why"), [
    (bytes_writer.layered_form(3, 1, basis=(0, 0)), "no mu but a sigma"),  # mu "none" beside sigma bytes
    (bytes_writer.layered_form(3, 3, detail=0), "no basis layer"),  # mu "none" needs a basis layer
    (bytes_writer.layered_form(3, 3, basis=(0, 50)), "project"),  # and an unprojected one
])
def test_malformed_forms_without_a_latent(form: bytes, why: str) -> None:
    payload = bytes_writer.f16(0.25) + bytes([3, 253, 0])
    with pytest.raises(BvaeFormatError, match=why) as caught:
        parse_bvae(_file(form, payload), "bad.bvae")
    assert type(caught.value) is BvaeFormatError and "bad.bvae" in str(caught.value)


def test_the_hand_written_form_reads_as_the_writer_writes_it() -> None:
    payload = bytes_writer.f16(0.25) + bytes([3, 253, 0])
    parsed = parse_bvae(_file(bytes_writer.layered_form(3, 3, basis=(0, 0)), payload))
    record = parsed.records[0]
    assert isinstance(record, LayeredRecord) and not record.has_latent
    assert same_layer(record.basis, BasisLayer(SHA, 0.25, np.array([3, -3, 0], np.int8)))
    assert encode_bvae([record], DecoderReference(parsed.header.decoder.sha256, "")) == _file(
        bytes_writer.layered_form(3, 3, basis=(0, 0)), payload)


# --------------------------------------------------------------------------- decoding


@pytest.fixture(scope="module")
def decoder() -> Any:
    from brdfcodec.codec import BrdfDecoder

    return BrdfDecoder()


def _linear_path_mean(decoder: Any) -> np.ndarray:
    """m over the whole (63, 90, 90) layout from the weight file itself: ``basis_mean`` (float16, one value per
    entry above the horizon, in increasing flat order) widened, 0 below the horizon (spec/model.md §1)."""
    from safetensors.numpy import load_file

    from brdfcodec.representation import to_network_layout
    from brdfcodec.representation.mask import kept_slice_horizon_mask

    mean = load_file(str(decoder.manifest.folder / "decoder.safetensors"))["basis_mean"].astype(np.float32)
    above = to_network_layout(kept_slice_horizon_mask()[None].repeat(3, axis=0)).reshape(-1)
    out = np.zeros(above.size, dtype=np.float32)
    out[above] = mean
    return out


@pytest.mark.parametrize("detail", [False, True])
def test_a_record_without_a_latent_decodes_to_the_mean_plus_its_layers_clamped(decoder: Any, detail: bool) -> None:
    basis = decoder.shared_basis
    record = without_latent(k=12, detail=detail, sha=basis.sha256, first=-250.0)  # dark: the clamp acts
    m = _linear_path_mean(decoder)
    expected = m.copy()
    expected[basis.entries] += record.basis.coefficients() @ basis.vectors(0, 12)
    if detail:
        from brdfcodec.layers.detail import decode_detail

        expected += decode_detail(record.detail).reshape(-1)  # type: ignore[arg-type]
    assert (expected[basis.entries] < 0).any()  # the clamp acts on the basis' entries
    expected = np.clip(expected, 0.0, MAPPED_MAX).reshape(NETWORK_INPUT_SHAPE)
    got = decoder.mapped_record(record)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5)
    # A few φd bins decode as the same bins of the whole table, up to the order of the basis sums.
    bins = [0, 45, 179]
    np.testing.assert_allclose(decoder.decode(record, phi_d_bins=bins), decoder.decode(record)[..., bins],
                               rtol=1e-4, atol=1e-5)
    (table,) = list(decoder.decode_many([record]))
    np.testing.assert_array_equal(table, decoder.decode(record))


def test_a_decoder_without_a_linear_path_refuses_them_naming_file_and_record(decoder: Any) -> None:
    import dataclasses

    import torch

    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.layers.basis import check_records_without_latent
    from brdfcodec.models.network import Decoder

    basis = decoder.shared_basis
    record = without_latent("no-path", sha=basis.sha256)
    config = dataclasses.replace(decoder.network.config, linear_basis=False)
    flat = BrdfDecoder.from_network(Decoder(config).eval())
    flat.__dict__["shared_basis"] = basis
    flat.reference, flat.manifest = decoder.reference, decoder.manifest
    with torch.no_grad(), pytest.raises(BasisError, match="'no-path'.*no linear path"):
        flat.mapped_record(record)
    header = parse_bvae(encode_bvae([record], decoder.reference)).header
    with pytest.raises(BasisError, match=r"lib\.bvae: record 'no-path'"):
        flat.check(header, "lib.bvae")  # refused when the file is opened for decoding (spec §7 step 10)
    decoder.check(header, "lib.bvae")  # the shipped decoder's linear path covers its basis
    with pytest.raises(BasisError, match=r"lib\.bvae: record 'no-path'.*no linear path"):
        check_records_without_latent(header.entries, decoder.basis_named, "lib.bvae", linear_path=False)
    check_records_without_latent(header.entries, decoder.basis_named, "lib.bvae", linear_path=True)


# --------------------------------------------------------------------------- rate control


def _slice_error(mapped: np.ndarray, target: np.ndarray, masks: np.ndarray) -> float:
    return float((np.abs(np.clip(mapped, 0.0, MAPPED_MAX) - target) * masks).sum())


def test_rate_control_keeps_the_lower_error_and_a_latent_on_a_tie() -> None:
    from brdfcodec.codec.rate import encode_layers

    target = np.full(NETWORK_INPUT_SHAPE, 0.5, dtype=np.float32)
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", np.zeros(8), np.full(8, 0.003))
    counts: list[int] = []

    def basis_fit(k: int, mu_storage: str | None, under_detail: bool):  # noqa: ANN202, ARG001
        return base, quantise_coefficients(SHA, np.ones(k)), target * 0.9  # 10 % off, whatever k

    def only(gain: float):  # noqa: ANN202
        def fit(k: int):  # noqa: ANN202
            counts.append(k)
            return quantise_coefficients(SHA, np.ones(k)), target * (1 - gain)
        return fit

    def run(budget: int, gain: float) -> Any:
        return encode_layers(base, target * 0.5, target, masks, bytes_budget=budget, basis_fit=basis_fit,
                             basis_count=75, basis_only_fit=only(gain)).record

    better = run(32, 0.05)
    assert not better.has_latent and better.basis.count == 32 - 5 and counts[-1] == 27
    assert run(32, 0.1).has_latent  # a tie: the record that can be edited
    assert run(32, 0.2).has_latent
    run(200, 0.05)
    assert counts[-1] == 75  # at most K coefficients
    small = run(8, 0.5)  # below every record with a latent (15 B): the one without, whatever its error
    assert not small.has_latent and small.basis.count == 3
    with pytest.raises(RateTargetError, match="5 bytes is below the smallest record's 6 bytes"):
        run(5, 0.05)


def test_a_larger_budget_is_never_worse_with_records_without_a_latent() -> None:
    """Budget ladder of synthetic fits whose error falls with k, the latent candidates flat (as in
    test_rate_monotone.py): each larger budget returns a record no worse than the smaller one's."""
    from brdfcodec.codec.rate import encode_layers, layered_mapped

    target = np.broadcast_to(np.linspace(0.2, 0.8, 90, dtype=np.float32), NETWORK_INPUT_SHAPE).copy()
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", np.zeros(8), np.ones(8))
    latent_mapped = target + np.float32(0.03)

    def basis_fit(k: int, mu_storage: str | None, under_detail: bool):  # noqa: ANN202, ARG001
        return base, quantise_coefficients(SHA, np.ones(k)), latent_mapped

    def only(k: int):  # noqa: ANN202  # better than the latent's 0.03 up to k = 7 coefficients, then worse
        return quantise_coefficients(SHA, np.ones(k)), target + np.float32(0.025 + 0.06 / np.sqrt(k))

    errors = []
    for budget in (6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 256):
        record = encode_layers(base, target + 0.1, target, masks, bytes_budget=budget, basis_fit=basis_fit,
                               basis_count=75, basis_only_fit=only).record
        latent = getattr(record, "has_latent", True)
        mapped = only(record.basis.count)[1] if not latent else layered_mapped(latent_mapped, record)
        errors.append((budget, latent, _slice_error(mapped, target, masks)))
    assert [e[1] for e in errors][:3] == [False, False, False]  # no latent record fits below 15 B
    assert all(e[1] for e in errors[3:])  # from 16 B the latent candidates fit, and win
    assert all(b[2] <= a[2] for a, b in zip(errors, errors[1:])), errors


@pytest.fixture(scope="module")
def encoder() -> Any:
    from brdfcodec.codec import BrdfEncoder

    return BrdfEncoder(effort=1, latent_dtype="float16")


def _encode(encoder: Any, brdf: Any, **options: Any) -> tuple[Any, float]:
    """One material under the given options (the encoder's model loaded once), and its kept-slice mapped L1."""
    from brdfcodec.codec.encoding import EncodeOptions
    from brdfcodec.representation import network_input_from_table

    encoder.options = EncodeOptions(effort=1, latent_itemsize=2, **options)
    inputs, mask = network_input_from_table(brdf.values, brdf.mask)
    (record,) = encoder.encode_arrays(["m"], inputs[None], mask[None], [brdf])
    return record, _slice_error(encoder.decoder.mapped_record(record), inputs, mask)


@pytest.mark.slow
def test_rate_control_picks_no_latent_where_better_and_is_never_worse(encoder: Any, analytic_tables) -> None:
    """Materials the model never saw: ``auto`` is at least as good as ``always`` on the error rate control ranks
    by, and picks a record without a latent where that is lower (gold at 16 B; gold at 32 B too before the coded
    μ's second grid, 2^−2, and green satin before records with μ coded in the layer's stream, format 2.5, kept
    their latent cheaper), not elsewhere (blue rubber at 16 B, where the latent's bytes buy more than the packed
    coefficients they would hold)."""
    picked = []
    for name, budget in (("green-satin", 32), ("blue-rubber", 16), ("gold", 16)):
        auto, auto_error = _encode(encoder, analytic_tables[name], bytes_budget=budget, latent="auto")
        always, always_error = _encode(encoder, analytic_tables[name], bytes_budget=budget, latent="always")
        assert getattr(always, "has_latent", True) and auto.meta["rate"]["record_bytes"] <= budget
        assert auto_error <= always_error * (1 + 1e-6), (name, budget, auto_error, always_error)
        if not getattr(auto, "has_latent", True):
            # packed (format 2.3) in the bytes of budget − 5 int8 coefficients: more of them
            assert auto_error < always_error and auto.basis.first == 0 and auto.basis.count > budget - 5
            assert auto.basis.top and auto.basis.nbytes + 3 <= budget
            picked.append((name, budget))
    assert ("gold", 16) in picked and ("blue-rubber", 16) not in picked


@pytest.mark.slow
def test_an_error_target_takes_a_smaller_record_without_a_latent_where_it_meets_it(encoder: Any,
                                                                                      analytic_tables) -> None:
    from brdfcodec.codec import measure

    brdf = analytic_tables["green-satin"]
    # the latent's candidates without the coded-μ records (format 2.5), which meet 0.045 in fewer bytes still
    auto, _ = _encode(encoder, brdf, max_relae=0.045, latent="auto", coded_mu_step=0)
    always, _ = _encode(encoder, brdf, max_relae=0.045, coded_mu_step=0)  # the default: a latent in every record
    assert always.has_latent
    assert not getattr(auto, "has_latent", True)  # without a latent, 0.045 is met in fewer bytes than with one
    assert auto.meta["rate"]["record_bytes"] < always.meta["rate"]["record_bytes"]
    assert measure(auto, encoder.decoder, brdf).meta["relae"]["mapped"] <= 0.045
    coded, _ = _encode(encoder, brdf, max_relae=0.045, latent="auto")  # with them: a latent, and no more bytes
    assert coded.has_latent and coded.coded_mu
    assert coded.meta["rate"]["record_bytes"] <= auto.meta["rate"]["record_bytes"]
    assert measure(coded, encoder.decoder, brdf).meta["relae"]["mapped"] <= 0.045


# --------------------------------------------------------------------------- edits, info, CLI, studio


def test_every_edit_refuses_a_record_without_a_latent() -> None:
    from brdfcodec.edit import latent_edits as edit
    record, other = without_latent(), LatentRecord("other", np.zeros(8), np.ones(8))
    for attempt in (lambda: edit.traverse(record, 0, [1.0]), lambda: edit.interpolate(record, other, 0.5),
                    lambda: edit.interpolate(other, record, 0.5), lambda: edit.mix_factors(record, other, [0]),
                    lambda: edit.graft(record, [0.0, 0.0], (3, 4)), lambda: edit.parameter_vector(record),
                    lambda: edit.with_parameters(record, np.zeros(8), name="x", edit={"op": "x"})):
        with pytest.raises(NoLatentError, match="'plain-pca' has no latent code.*--latent always"):
            attempt()


def _library(path: Path, records: list, decoder: Any) -> Path:
    path.write_bytes(encode_bvae(records, decoder.reference))
    return path


def test_cli_edit_info_and_decompress(decoder: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from brdfcodec.cli.main import main

    basis = decoder.shared_basis
    lib = _library(tmp_path / "lib.bvae", [without_latent(sha=basis.sha256)], decoder)
    out = tmp_path / "edited.bvae"
    assert main(["edit", "traverse", str(lib), "--dim", "1", "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(lib) in err[0] and "'plain-pca' has no latent code" in err[0]
    assert "bvae compress --latent always" in err[0] and "Traceback" not in err[0] and not out.exists()
    assert main(["info", str(lib)]) == 0
    shown = capsys.readouterr().out
    assert "format 2.1" in shown and "[layered] latent: none (basis only), basis 5 (vectors 1–5)" in shown
    assert "7 B payload, 10 B with its index entry" in shown
    assert main(["info", "--json", str(lib)]) == 0
    (item,) = json.loads(capsys.readouterr().out)["materials"]
    assert item["latent"] is False and item["mu"] == item["sigma"] == "none"
    decoded = tmp_path / "out.npy"
    assert main(["decompress", str(lib), "-o", str(decoded), "--phi-d", "0,90"]) == 0  # decodes like any other
    assert np.load(decoded).shape == (3, 90, 90, 2)


@pytest.mark.slow
def test_cli_latent_flag_and_the_bytes_floor(red_plastic_file: Path, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    from brdfcodec.cli.main import main

    small = tmp_path / "small.bvae"  # below every record with a latent: one without it (a name of 11 bytes)
    assert main(["compress", str(red_plastic_file), "-o", str(small), "--bytes", "10", "--effort", "0",
                 "--latent", "auto"]) == 0
    assert "(no latent: basis only, not editable)" in capsys.readouterr().out
    (entry,) = parse_bvae(small.read_bytes()).header.entries
    assert entry.layers["mu"] == "none" and entry.layers["basis"]["count"] >= 5  # packed: at least as many
    assert entry.length + entry.descriptor_bytes <= 10
    for flags, message in ((["--bytes", "5", "--latent", "auto"], "--bytes 5 is below the smallest record"),
                           (["--bytes", "9", "--latent", "always"], "--bytes 9 is below the smallest record"),
                           (["--bytes", "9"], "--bytes 9 is below the smallest record"),  # always, the default
                           (["--latent", "always"], "--latent chooses between the records of rate control")):
        bad = tmp_path / "bad.bvae"
        assert main(["compress", str(red_plastic_file), "-o", str(bad), *flags]) == 2
        err = capsys.readouterr().err
        assert message in err and not bad.exists()


def test_the_studio_leaves_records_without_a_latent_out(decoder: Any, tmp_path: Path) -> None:
    from brdfcodec.studio.catalogue import Catalogue

    basis = decoder.shared_basis
    mixed = _library(tmp_path / "mixed.bvae", [LatentRecord("gold", np.zeros(8), np.ones(8)),
                                               without_latent(sha=basis.sha256)], decoder)
    catalogue = Catalogue([mixed])
    assert catalogue.ids() == ["gold"] and catalogue.without_latent == ["plain-pca"]
    info = catalogue.describe()
    assert info["without_latent"] == ["plain-pca"] and [m["id"] for m in info["materials"]] == ["gold"]
    alone = _library(tmp_path / "alone.bvae", [without_latent(sha=basis.sha256)], decoder)
    with pytest.raises(ValueError, match="no material to edit.*--latent always"):
        Catalogue([alone])
