"""Format 2.4: entropy-coded basis layers (``spec/bvae-format.md`` §4.8, :mod:`brdfcodec.layers.coded_basis`)."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.errors import BvaeFormatError, UnsupportedVersionError
from brdfcodec.format.bvae import DecoderReference, encode_bvae, parse_bvae, record_size
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.layers.basis_layer import BasisLayer, coded_coefficients
from brdfcodec.layers.coded_basis import (
    MAX_MAGNITUDE,
    PRIOR_CODE_LIMIT,
    STOP_PROBABILITY,
    ZERO_PROBABILITY,
    choose_coding,
    decode_integers,
    encode_integers,
    prior_codes,
)
from brdfcodec.layers.packed import packed_step

SHA = "ab" * 32
DECODER = DecoderReference("cd" * 32, "test")


def _laplace(seed: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    codes = rng.integers(-PRIOR_CODE_LIMIT, PRIOR_CODE_LIMIT + 1, k)
    q = np.rint(rng.laplace(0.0, 2.0 ** (codes / 16) / np.sqrt(2))).astype(np.int64)
    return q, codes


@pytest.mark.parametrize("seed", range(40))
def test_integers_round_trip_exactly(seed: int) -> None:
    q, codes = _laplace(seed, 1 + seed * 2)
    if seed % 7 == 0:
        q[0] = (-1) ** seed * (MAX_MAGNITUDE - seed)  # the escape's longest prefix
    data = encode_integers(q, codes)
    assert decode_integers(data, codes).tolist() == q.tolist()
    assert not data or data[-1] != 0  # the shortest bytes never end in a zero byte (the decoder reads zeros)


def test_the_code_is_close_to_the_prior_entropy() -> None:
    rng = np.random.default_rng(3)
    codes = np.full(4000, 16)  # σ = 2 steps
    q = np.rint(rng.laplace(0.0, 2.0 / np.sqrt(2), len(codes))).astype(np.int64)
    _, counts = np.unique(q, return_counts=True)
    p = counts / counts.sum()
    entropy = -(p * np.log2(p)).sum() * len(q)
    assert 8 * len(encode_integers(q, codes)) < 1.02 * entropy


def test_all_zero_integers_take_no_bytes_and_bounds_are_refused() -> None:
    assert encode_integers(np.zeros(9, np.int64), np.zeros(9, np.int64)) == b""
    with pytest.raises(ValueError, match="exceeds"):
        encode_integers([MAX_MAGNITUDE + 1], [0])
    with pytest.raises(ValueError, match="prefix"):  # all-ones bytes: an escape prefix past its limit
        decode_integers(b"\xff" * 16, [PRIOR_CODE_LIMIT])


def test_probability_tables_sit_away_from_rounding_boundaries() -> None:
    """Every binary64 exp gives the same tables (the spec lists them): no entry within 1e-6 of a half."""
    codes = np.arange(-PRIOR_CODE_LIMIT, PRIOR_CODE_LIMIT + 1)
    b = 2.0 ** (codes / 16) / np.sqrt(2.0)
    for scaled, table in ((256 * -np.expm1(-1 / (2 * b)), ZERO_PROBABILITY),
                          (256 * -np.expm1(-1 / b), STOP_PROBABILITY)):
        inside = (scaled > 1) & (scaled < 255)
        assert (np.abs(scaled[inside] - np.floor(scaled[inside]) - 0.5) > 1e-6).all()
        assert list(table) == np.clip(np.floor(scaled + 0.5), 1, 255).astype(int).tolist()
    assert all(1 <= p <= 255 for p in ZERO_PROBABILITY + STOP_PROBABILITY)


def test_prior_codes_follow_the_power_law() -> None:
    # c = A − e + 64 − ⌊(d·round(32 log2 n) + 32) / 64⌋ with round(32 log2 n) = 0, 32, 51, 64 for n = 1 … 4
    assert prior_codes(76, 32, 100, 0, 4).tolist() == [40, 40 - 16, 40 - 26, 40 - 32]
    assert prior_codes(255, 0, 0, 0, 2).tolist() == [PRIOR_CODE_LIMIT] * 2  # clipped


def test_choose_coding_fits_the_budget_and_beats_fewer_bytes() -> None:
    rng = np.random.default_rng(5)
    c = rng.laplace(0, 1, 70) * np.arange(9, 79) ** -0.8
    errors = []
    for budget in (4, 8, 16, 32, 64):
        choice = choose_coding(c, 8, budget, 128, 32)
        assert choice is not None and 1 + len(choice.data) <= budget
        s = packed_step(choice.step_code)
        k = len(choice.q)
        assert np.isclose(choice.error, ((c[:k] - s * choice.q) ** 2).sum() + (c[k:] ** 2).sum())
        errors.append(choice.error)
    assert errors == sorted(errors, reverse=True) and errors[-1] < 0.05 * errors[0]
    assert choose_coding(c, 8, 0, 128, 32) is None


def _coded_record(name: str = "gold", *, latent: bool = True) -> LayeredRecord:
    rng = np.random.default_rng(1)
    c = rng.laplace(0, 1, 60) * np.arange(9, 69) ** -0.8
    layer = coded_coefficients(SHA, c, 20, (128, 40), first=8 if latent else 0)
    assert layer is not None and layer.prior == (128, 40) and layer.nbytes <= 20
    if not latent:
        return LayeredRecord.without_latent(name, 8, layer)
    return LayeredRecord(name, np.linspace(-1, 1, 8), np.ones(8), basis=layer, compact_mu=True, fixed_mu_grid=True,
                         store_sigma=False)


def test_records_round_trip_and_state_version_2_4() -> None:
    records = [_coded_record(), _coded_record("pca", latent=False)]
    data = encode_bvae(records, DECODER)
    assert data[8:12] == bytes([2, 0, 4, 0])
    parsed = parse_bvae(data)
    for record in records:
        back = parsed.record(record.name)
        assert isinstance(back, LayeredRecord) and back.basis is not None and record.basis is not None
        assert back.basis.q.tolist() == record.basis.q.tolist() and back.basis.step == record.basis.step
        assert (back.basis.prior, back.basis.first, back.basis.count) == (
            record.basis.prior, record.basis.first, record.basis.count)
        np.testing.assert_array_equal(back.basis.coefficients(), record.basis.coefficients())
        # what a size budget counts: the payload and a descriptor with the count and the layer's length
        entry = next(e for e in parsed.header.entries if e.name == record.name)
        assert entry.length + entry.descriptor_bytes == record_size(record)
        assert entry.layers["basis"]["length"] == record.basis.nbytes


def test_malformed_and_unknown_coded_layers_are_refused() -> None:
    import zlib

    data = bytearray(encode_bvae([_coded_record("pca", latent=False)], DECODER))
    header_length = int.from_bytes(data[16:20], "little")

    def with_crcs(raw: bytearray) -> bytes:
        raw = bytearray(raw)
        payload_start = 24 + header_length
        crc_at = payload_start - 4  # no metadata block: the payload CRC ends the header
        raw[crc_at:payload_start] = zlib.crc32(bytes(raw[payload_start:])).to_bytes(4, "little")
        raw[20:24] = zlib.crc32(bytes(raw[:20]) + bytes(raw[24:payload_start])).to_bytes(4, "little")
        return bytes(raw)

    layer_byte = 24 + 32 + 2 + 1 + 32 + 1 + 3  # decoder, latent_dim, dtype, basis, form count, kind, mu, sigma
    assert data[layer_byte] == 1 | 8
    both = bytearray(data)
    both[layer_byte] = 1 | 4 | 8  # packed and coded
    with pytest.raises(BvaeFormatError, match="excludes bit 2"):
        parse_bvae(with_crcs(both))
    unknown = bytearray(data)
    unknown[layer_byte] = 1 | 16
    with pytest.raises(UnsupportedVersionError):
        parse_bvae(with_crcs(unknown))
    padded = bytearray(data)
    padded += b"\x00"  # a longer coding of the same integers: the length in the descriptor says one byte more
    payload_start = 24 + header_length
    length_at = payload_start - 4 - 1  # the record's last descriptor field, a one-byte varint
    padded[length_at] += 1
    with pytest.raises(BvaeFormatError, match="shortest"):
        parse_bvae(with_crcs(padded))


def test_a_coded_layer_checks_its_fields() -> None:
    with pytest.raises(ValueError, match="prior"):
        BasisLayer(SHA, packed_step(100), np.ones(3, np.int64), prior=(256, 0))
    with pytest.raises(ValueError, match="packed or entropy-coded"):
        BasisLayer(SHA, packed_step(100), np.ones(3, np.int64), top=9, prior=(1, 0))
    with pytest.raises(ValueError, match="packed step"):
        BasisLayer(SHA, 0.3, np.ones(3, np.int64), prior=(1, 0))


@pytest.mark.slow  # an encode with the shipped model
def test_the_cli_writes_coded_layers_within_the_budget_and_they_decode_as_written(red_plastic_file, tmp_path) -> None:
    """``bvae compress --bytes 32 --basis-coding coded``: a 2.4 file whose record keeps its latent, fits the
    budget (descriptor with the layer's length included) and decodes to what the encoder measured."""
    from brdfcodec.cli.main import main
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import read_bvae

    out = tmp_path / "coded.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(out), "--bytes", "32", "--basis-coding", "coded",
                 "--no-measure"]) == 0
    data = out.read_bytes()
    parsed = parse_bvae(data)
    (entry,) = parsed.header.entries
    (record,) = read_bvae(out).records
    # 2.6: bvae compress names the decoder and basis by short references (spec §3.1); with --full-references, 2.4,
    # or 2.5 where rate control kept a record whose μ rides in the coded layer (spec §4.9)
    assert data[8:12] == bytes([2, 0, 6, 0])
    full = tmp_path / "full.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(full), "--bytes", "32", "--basis-coding", "coded",
                 "--no-measure", "--full-references"]) == 0
    assert full.read_bytes()[8:12] == bytes([2, 0, 5 if record.coded_mu else 4, 0])
    assert record.has_latent and record.basis is not None and record.basis.prior is not None
    assert entry.length + entry.descriptor_bytes <= 32 and entry.layers["basis"]["length"] == record.basis.nbytes
    table = BrdfDecoder().decode(record)
    assert np.isfinite(table).all()


def test_info_names_a_coded_layer_and_its_prior(tmp_path, capsys) -> None:
    import json

    from brdfcodec.cli.main import main

    path = tmp_path / "coded.bvae"
    path.write_bytes(encode_bvae([_coded_record("pca", latent=False)], DECODER))
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "format 2.4" in out and "entropy-coded, prior 128/40" in out
    assert main(["info", "--json", str(path)]) == 0
    (item,) = json.loads(capsys.readouterr().out)["materials"]
    assert item["basis"]["coded_prior"] == [128, 40] and item["basis"]["coded_bytes"] <= 20


@pytest.mark.parametrize("seed", range(6))
def test_every_prefix_size_is_the_length_of_that_prefix_coded(seed: int) -> None:
    from brdfcodec.layers.coded_basis import coded_prefix_sizes

    q, codes = _laplace(100 + seed, 5 + 30 * seed)
    q[::4] = 0
    if seed % 3 == 0:
        q[-1] = MAX_MAGNITUDE - seed  # an escape at the end
    sizes = coded_prefix_sizes(q, codes)
    assert sizes == [len(encode_integers(q[:k], codes[:k])) for k in range(len(q) + 1)]


def test_the_writer_declares_the_prior_under_which_the_coefficients_cost_least() -> None:
    """``CODED_PRIORS``: a residual whose spread is what the first prior expects keeps it; one three times as wide
    (a material unlike the training ones) gets the wider prior, and a smaller squared error in the same bytes than
    under the first."""
    from brdfcodec.codec.encoding import CODED_PRIOR, CODED_PRIORS, _coded_prior_and_count

    rng = np.random.default_rng(3)
    for latent, first in ((True, 8), (False, 0)):
        priors = CODED_PRIORS[latent]
        assert priors[0] == CODED_PRIOR[latent] and len(set(priors)) == len(priors)
        amplitude, decay = priors[0]
        vectors = np.arange(first + 1, first + 193, dtype=np.float64)
        spread = 2.0 ** (amplitude / 16 - 4) * vectors ** (-decay / 32) / np.sqrt(2)  # the Laplace scale
        assert _coded_prior_and_count(rng.laplace(0, 1, 192) * spread, first, 60, priors)[0] == priors[0]
        wide = rng.laplace(0, 1, 192) * spread * 3
        prior, count = _coded_prior_and_count(wide, first, 60, priors)
        assert prior == priors[1] and count >= 1
        under = {p: choose_coding(wide, first, 60, *p).error for p in priors}
        assert under[priors[1]] < under[priors[0]]
    with pytest.raises(ValueError, match="no coded basis layer fits"):
        _coded_prior_and_count(np.ones(4), 0, 0, CODED_PRIORS[False])


def test_records_under_two_priors_share_a_file_as_two_forms() -> None:
    from brdfcodec.codec.encoding import CODED_PRIORS

    rng = np.random.default_rng(2)
    records = []
    for name, prior in zip(("narrow", "wide"), CODED_PRIORS[True]):
        layer = coded_coefficients(SHA, rng.laplace(0, 30, 40), 20, prior, first=8)
        assert layer is not None and layer.prior == prior
        records.append(LayeredRecord(name, np.zeros(8), np.ones(8), basis=layer, compact_mu=True,
                                     fixed_mu_grid=True, store_sigma=False))
    parsed = parse_bvae(encode_bvae(records, DECODER))
    assert parsed.header.form_count == 2
    for record in records:
        back = parsed.record(record.name)
        assert back.basis.prior == record.basis.prior and back.basis.q.tolist() == record.basis.q.tolist()
