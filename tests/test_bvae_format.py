"""The .bvae format: round trips, an independent reader written from the spec, corruption and fuzzing."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from brdfcodec.bvae_format import (
    FORMAT_MAJOR,
    FORMAT_MINOR,
    MAGIC,
    MAX_HEADER_BYTES,
    BvaeReader,
    DecoderReference,
    GraftRecord,
    LatentRecord,
    encode_bvae,
    parse_bvae,
    read_bvae,
    read_header,
    write_bvae,
)
from brdfcodec.errors import BvaeChecksumError, BvaeFormatError, UnsupportedVersionError

SPEC = Path(__file__).resolve().parents[1] / "spec" / "bvae-format.md"
DECODER = DecoderReference("ab" * 32, "test-decoder")


def library(count: int = 3, dim: int = 8) -> list[LatentRecord | GraftRecord]:
    rng = np.random.default_rng(count)
    records: list[LatentRecord | GraftRecord] = [
        LatentRecord(f"mat-{i}", rng.normal(size=dim), np.exp(rng.normal(size=dim) - 2), {"source_sha256": "cd" * 32})
        for i in range(count)
    ]
    records.append(GraftRecord("grafted", rng.normal(size=dim), np.full(dim, 0.1), (0, dim - 1), [1.5, -2.0]))
    return records


def spec_reader(data: bytes) -> tuple[dict, list[np.ndarray]]:
    """A reader written from spec/bvae-format.md alone (no brdfcodec code)."""
    magic, major, minor, flags, length, crc = struct.unpack_from("<8sHHIII", data, 0)
    assert magic == b"\x89BVAE\r\n\x1a" and major == 1 and flags & ~1 == 0
    stored = data[24 : 24 + length]
    assert zlib.crc32(data[:20] + stored) == crc
    if flags & 1:
        import zstandard

        stored = zstandard.ZstdDecompressor().decompress(stored)
    header = json.loads(stored)
    dtype = {"float32": "<f4", "float16": "<f2"}[header["latent_dtype"]]
    base = 24 + length
    payloads = []
    for entry in header["records"]:
        raw = data[base + entry["offset"] : base + entry["offset"] + entry["length"]]
        assert zlib.crc32(raw) == entry["crc32"]
        payloads.append(np.frombuffer(raw, dtype=dtype))
    last = header["records"][-1]
    assert len(data) == base + last["offset"] + last["length"]
    return header, payloads


@pytest.mark.parametrize("dtype", ["float32", "float16"])
@pytest.mark.parametrize("compress", [True, False])
def test_round_trip_and_independent_reader(dtype: str, compress: bool) -> None:
    records = library()
    data = encode_bvae(records, DECODER, latent_dtype=dtype, compress_header=compress)  # type: ignore[arg-type]
    parsed = parse_bvae(data)
    assert parsed.header.decoder == DECODER and parsed.header.names == [r.name for r in records]
    tolerance = 0 if dtype == "float32" else 2e-3
    for original, back in zip(records, parsed.records, strict=True):
        assert type(back) is type(original) and back.meta == original.meta
        np.testing.assert_allclose(back.mu, original.mu, rtol=tolerance, atol=tolerance)
        np.testing.assert_allclose(back.sigma, original.sigma, rtol=tolerance)
    header, payloads = spec_reader(data)
    assert header["decoder"] == {"sha256": DECODER.sha256, "name": DECODER.name}
    np.testing.assert_array_equal(payloads[0][:8].astype(np.float32), parsed.records[0].mu)
    graft = parsed.records[-1]
    assert isinstance(graft, GraftRecord) and graft.graft_dims == (0, 7)
    np.testing.assert_allclose(payloads[-1][16:], [1.5, -2.0])
    assert encode_bvae(records, DECODER, latent_dtype=dtype, compress_header=compress) == data  # deterministic


def test_latent_payload_is_64_bytes_in_float32() -> None:
    data = encode_bvae([LatentRecord("a", np.zeros(8), np.ones(8))], DECODER)
    assert parse_bvae(data).header.entries[0].length == 64
    half = encode_bvae([LatentRecord("a", np.zeros(8), np.ones(8))], DECODER, latent_dtype="float16")
    assert parse_bvae(half).header.entries[0].length == 32


def test_spec_states_the_limits_the_code_uses() -> None:
    text = SPEC.read_text(encoding="utf-8")
    assert f"Format version {FORMAT_MAJOR}.{FORMAT_MINOR} " in text
    assert f"**{MAX_HEADER_BYTES:,}** bytes" in text
    assert "`89 42 56 41 45 0D 0A 1A`" in text and MAGIC == bytes.fromhex("89 42 56 41 45 0D 0A 1A")
    assert "**64 bytes** for D = 8 in float32" in text


def test_random_access_reads_only_the_asked_record(tmp_path: Path) -> None:
    path = tmp_path / "lib.bvae"
    write_bvae(path, library(20), DECODER)
    with BvaeReader(path) as reader:
        assert len(reader.names) == 21
        record = reader.read("mat-7")
        assert record.name == "mat-7"
        with pytest.raises(KeyError, match="mat-7"):
            reader.read("missing")
    assert read_header(path).file_size == path.stat().st_size


def test_write_refuses_to_overwrite_and_leaves_no_partial_file(tmp_path: Path) -> None:
    path = tmp_path / "a.bvae"
    write_bvae(path, library(1), DECODER)
    before = path.read_bytes()
    with pytest.raises(FileExistsError):
        write_bvae(path, library(2), DECODER)
    assert path.read_bytes() == before
    with pytest.raises(ValueError, match="unique"):
        write_bvae(tmp_path / "b.bvae", [library(1)[0], library(1)[0]], DECODER)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bvae"]


def test_invalid_records_are_refused() -> None:
    with pytest.raises(ValueError, match="finite"):
        LatentRecord("a", [np.nan] * 8, np.ones(8))
    with pytest.raises(ValueError, match="> 0"):
        LatentRecord("a", np.zeros(8), np.zeros(8))
    with pytest.raises(ValueError, match="control"):
        LatentRecord("a\nb", np.zeros(8), np.ones(8))
    with pytest.raises(ValueError, match="float16"):
        encode_bvae([LatentRecord("a", np.full(8, 1e6), np.ones(8))], DECODER, latent_dtype="float16")
    with pytest.raises(ValueError, match="graft_dims"):
        GraftRecord("g", np.zeros(8), np.ones(8), (0, 0), [1, 2])


def _rewrap(data: bytes, *, flags: int | None = None, major: int | None = None, header_edit=None) -> bytes:
    """Rebuild a file with a changed preamble field or header, with valid checksums."""
    magic, old_major, minor, old_flags, length, _ = struct.unpack_from("<8sHHIII", data, 0)
    stored = data[24 : 24 + length]
    assert not old_flags & 1
    if header_edit is not None:
        stored = json.dumps(header_edit(json.loads(stored))).encode()
    head = struct.pack("<8sHHII", magic, old_major if major is None else major, minor,
                       old_flags if flags is None else flags, len(stored))
    return head + struct.pack("<I", zlib.crc32(head + stored)) + stored + data[24 + length :]


def test_unknown_versions_flags_and_kinds_are_refused() -> None:
    data = encode_bvae(library(1), DECODER, compress_header=False)
    with pytest.raises(UnsupportedVersionError, match="version 2"):
        parse_bvae(_rewrap(data, major=2))
    with pytest.raises(UnsupportedVersionError, match="flag bits"):
        parse_bvae(_rewrap(data, flags=2))

    def new_kind(header: dict) -> dict:
        header["records"][0]["kind"] = "neural-field"
        return header

    with pytest.raises(UnsupportedVersionError, match="neural-field"):
        parse_bvae(_rewrap(data, header_edit=new_kind))

    def extra_field(header: dict) -> dict:
        header["future_optional"] = {"x": 1}
        return header

    assert parse_bvae(_rewrap(data, header_edit=extra_field)).header.names == ["mat-0", "grafted"]


def test_trailing_bytes_and_wrong_magic_are_refused() -> None:
    data = encode_bvae(library(1), DECODER)
    with pytest.raises(BvaeFormatError, match="trailing"):
        parse_bvae(data + b"\0")
    with pytest.raises(BvaeFormatError, match="magic"):
        parse_bvae(b"MERL" + data[4:])
    with pytest.raises(BvaeFormatError, match="magic"):
        parse_bvae(b"")


@pytest.mark.parametrize("compress", [True, False])
def test_every_truncation_and_every_single_byte_change_is_detected(compress: bool) -> None:
    data = encode_bvae(library(2), DECODER, compress_header=compress)
    for cut in range(len(data)):
        with pytest.raises(BvaeFormatError):
            parse_bvae(data[:cut])
    for position in range(len(data)):
        for delta in (1, 0x80, 0xFF):
            corrupt = bytearray(data)
            corrupt[position] ^= delta
            with pytest.raises(BvaeFormatError):
                parse_bvae(bytes(corrupt))


def test_checksum_errors_are_typed() -> None:
    data = bytearray(encode_bvae(library(1), DECODER))
    data[-1] ^= 1
    with pytest.raises(BvaeChecksumError, match="grafted"):
        parse_bvae(bytes(data))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=2048))
def test_fuzz_random_bytes_only_raise_format_errors(blob: bytes) -> None:
    for data in (blob, MAGIC + blob, _VALID[:24] + blob):
        try:
            parse_bvae(data)
        except BvaeFormatError:
            pass


_VALID = encode_bvae(library(2), DECODER, compress_header=False)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.integers(0, len(_VALID) - 1), st.integers(1, 255)), min_size=1, max_size=8))
def test_fuzz_mutations_of_a_valid_file(changes: list[tuple[int, int]]) -> None:
    data = bytearray(_VALID)
    for position, delta in changes:
        data[position] ^= delta
    try:
        parsed = parse_bvae(bytes(data))
    except BvaeFormatError:
        return
    # Every byte lies under a CRC-32: only changes that cancel out (the same bit flipped twice) may parse.
    assert bytes(data) == _VALID, "a corruption was not detected"
    assert parsed.header.names == ["mat-0", "mat-1", "grafted"]


@settings(max_examples=200, deadline=None)
@given(
    st.dictionaries(st.text(max_size=8), st.recursive(st.none() | st.booleans() | st.integers() | st.text(max_size=8),
                    lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=4), c, max_size=3)),
                    max_size=4)
)
def test_fuzz_header_json_content(extra: dict) -> None:
    """Arbitrary JSON substituted for header fields only raises format errors."""
    def edit(header: dict) -> dict:
        header["records"][0].update(extra)
        header.update(extra)
        return header

    try:
        parse_bvae(_rewrap(_VALID, header_edit=edit))
    except BvaeFormatError:
        pass


def test_read_bvae_on_files(tmp_path: Path) -> None:
    path = tmp_path / "x.bvae"
    write_bvae(path, library(2), DECODER)
    assert read_bvae(path).header.names == ["mat-0", "mat-1", "grafted"]
    with pytest.raises(IsADirectoryError):
        read_bvae(tmp_path)
    with pytest.raises(FileNotFoundError):
        read_bvae(tmp_path / "missing.bvae")
