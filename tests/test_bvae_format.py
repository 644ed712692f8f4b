"""The .bvae format: round trips, an independent reader written from the spec, corruption and fuzzing."""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from brdfcodec.errors import BvaeChecksumError, BvaeFormatError, UnsupportedVersionError
from brdfcodec.format.bvae import (
    FORMAT_MAJOR,
    FORMAT_MINOR,
    MAGIC,
    MAX_FORMS,
    MAX_HEADER_BYTES,
    MAX_RECORDS,
    PROVENANCE_KEYS,
    BvaeReader,
    DecoderReference,
    GraftRecord,
    LatentRecord,
    encode_bvae,
    parse_bvae,
    read_bvae,
    read_header,
    record_overhead,
    record_size,
    without_provenance,
    write_bvae,
)

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
    """A reader of latent and graft records written from spec/bvae-format.md alone (no brdfcodec code)."""
    magic, major, minor, flags, length, crc = struct.unpack_from("<8sHHIII", data, 0)
    assert magic == b"\x89BVAE\r\n\x1a" and (major, minor) == (2, 1) and flags & ~3 == 0
    stored = data[24 : 24 + length]
    assert zlib.crc32(data[:20] + stored) == crc
    at = 0

    def take(count: int) -> bytes:
        nonlocal at
        at += count
        assert at <= len(stored)
        return stored[at - count : at]

    def varint() -> int:
        value, shift = 0, 0
        while True:
            byte = take(1)[0]
            value |= (byte & 0x7F) << shift
            shift += 7
            if not byte & 0x80:
                return value

    decoder = take(32).hex()
    dim, dtype_code = struct.unpack("<HB", take(3))
    basis = take(32).hex() if flags & 2 else None
    forms = []
    for _ in range(take(1)[0]):
        kind = take(1)[0]
        assert kind in (0, 1)  # latent, graft
        forms.append((kind, [varint() for _ in range(varint())] if kind == 1 else []))
    index = []
    for _ in range(varint()):
        name = take(varint()).decode("utf-8")
        index.append((name, *forms[take(1)[0]]))
    (payload_crc,) = struct.unpack("<I", take(4))
    block = stored[at:]
    if flags & 1:
        import zstandard

        block = zstandard.ZstdDecompressor().decompress(block)
    metadata = json.loads(block) if block else {}
    start = 24 + length
    assert zlib.crc32(data[start:]) == payload_crc
    dtype = ("<f4", "<f2")[dtype_code]
    payloads = []
    for _, _, dims in index:
        size = (2 * dim + len(dims)) * np.dtype(dtype).itemsize
        payloads.append(np.frombuffer(data[start : start + size], dtype=dtype))
        start += size
    assert start == len(data)
    header = {"decoder": decoder, "basis": basis, "latent_dim": dim, "names": [n for n, _, _ in index],
              "graft_dims": [d for _, _, d in index], "metadata": metadata}
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
    assert header["decoder"] == DECODER.sha256 and header["basis"] is None and header["latent_dim"] == 8
    assert header["metadata"]["decoder_name"] == DECODER.name  # the records have metadata: so has the file
    assert header["metadata"]["records"] == {r.name: r.meta for r in records if r.meta}
    assert header["names"] == [r.name for r in records] and header["graft_dims"][-1] == [0, 7]
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
    assert f"| header (index and stored metadata block) | {MAX_HEADER_BYTES:,} bytes |" in text
    assert f"| record forms per file | {MAX_FORMS} |" in text and f"| records per file | {MAX_RECORDS:,} |" in text
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
    """Rebuild a file with a changed preamble field or header bytes, with a valid header CRC."""
    magic, old_major, minor, old_flags, length, _ = struct.unpack_from("<8sHHIII", data, 0)
    stored = data[24 : 24 + length]
    if header_edit is not None:
        stored = header_edit(stored)
    head = struct.pack("<8sHHII", magic, old_major if major is None else major, minor,
                       old_flags if flags is None else flags, len(stored))
    return head + struct.pack("<I", zlib.crc32(head + stored)) + stored + data[24 + length :]


def _metadata_at(stored: bytes) -> int:
    """Where an uncompressed metadata block starts in a header written by :func:`encode_bvae`."""
    return stored.index(b'{"created_by"')


def test_unknown_versions_flags_and_kinds_are_refused() -> None:
    data = encode_bvae(library(1), DECODER, compress_header=False)
    with pytest.raises(UnsupportedVersionError, match="version 3"):
        parse_bvae(_rewrap(data, major=3))
    with pytest.raises(UnsupportedVersionError, match="development format 1.x"):
        parse_bvae(_rewrap(data, major=1))
    with pytest.raises(UnsupportedVersionError, match="flag bits"):
        parse_bvae(_rewrap(data, flags=8))  # bit 3: bit 2 is known since 2.6 (short references)
    # 32 bytes of decoder hash, latent_dim, latent_dtype, the form count: then the first form's kind.
    with pytest.raises(UnsupportedVersionError, match="record kind 7"):
        parse_bvae(_rewrap(data, header_edit=lambda h: h[:36] + b"\x07" + h[37:]))
    with pytest.raises(UnsupportedVersionError, match="latent dtype code 5"):
        parse_bvae(_rewrap(data, header_edit=lambda h: h[:34] + b"\x05" + h[35:]))

    def extra_field(stored: bytes) -> bytes:
        at = _metadata_at(stored)
        block = json.loads(stored[at:])
        return stored[:at] + json.dumps({**block, "future_optional": {"x": 1}}).encode()

    assert parse_bvae(_rewrap(data, header_edit=extra_field)).header.names == ["mat-0", "grafted"]


def test_a_default_file_is_names_descriptors_and_payloads() -> None:
    """Without metadata a file holds no metadata block (no decoder name, no created_by) and states the decoder,
    the latent dtype and each record form once: 24 + 32 + 3 + 1 + 1 + 1 + 4 fixed bytes and per record its
    name, 2 bytes of descriptor and its payload."""
    plain = [LatentRecord(f"m{i}", np.zeros(8), np.ones(8)) for i in range(3)]
    data = encode_bvae(plain, DECODER)
    assert len(data) == 24 + 32 + 3 + 1 + 1 + 1 + 4 + sum(len(r.name) + 2 + 64 for r in plain)
    parsed = parse_bvae(data)
    assert parsed.header.decoder == DecoderReference(DECODER.sha256, "") and parsed.header.created_by == ""
    assert parsed.header.form_count == 1 and all(r.meta == {} for r in parsed.records)
    assert DECODER.name.encode() not in data and b"created_by" not in data
    with_meta = encode_bvae([LatentRecord("m0", np.zeros(8), np.ones(8), {"effort": 1}), *plain[1:]], DECODER)
    assert parse_bvae(with_meta).header.decoder == DECODER  # a metadata block names the decoder and the writer


def test_record_size_is_what_a_record_adds_beyond_its_name() -> None:
    """:func:`record_size` is exact for every kind, form and number size (a count of 128 takes a 2-byte varint,
    a name of 128 bytes too), so rate control can hold a budget on the file, not the payload."""
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.detail import DetailLayer

    rng = np.random.default_rng(1)
    frame = _detail_frame()
    made = [
        LatentRecord("a", np.zeros(8), np.ones(8)),
        LatentRecord("é" * 64, np.zeros(8), np.ones(8)),  # 128 bytes of name: a 2-byte length
        GraftRecord("g", np.zeros(8), np.ones(8), (1, 2), [0.5, 1.0]),
        LayeredRecord("b", np.linspace(-1, 1, 8), np.full(8, 0.1), basis=BasisLayer(
            "cd" * 32, 0.5, rng.integers(-9, 9, 5).astype(np.int8), 8, 50), compact_mu=True, shared_sigma=True,
            fixed_mu_grid=True),
        LayeredRecord("c", np.linspace(-1, 1, 8), np.full(8, 0.1), basis=BasisLayer(
            "cd" * 32, 0.5, rng.integers(-9, 9, 130).astype(np.int8), 0), compact_sigma=True),
        LayeredRecord("d", np.zeros(8), np.ones(8), detail=DetailLayer(0.25, "int16", frame), basis=BasisLayer(
            "cd" * 32, 0.5, rng.integers(-9, 9, 3).astype(np.int8), 8), compact_sigma=True),
    ]
    for dtype in ("float32", "float16"):
        for record in made:
            alone = encode_bvae([LatentRecord("z", np.zeros(8), np.ones(8)), record], DECODER,
                                latent_dtype=dtype)  # type: ignore[arg-type]
            twice = encode_bvae([LatentRecord("z", np.zeros(8), np.ones(8)), record,
                                 replace(record, name=record.name + "2")], DECODER,
                                latent_dtype=dtype)  # type: ignore[arg-type]
            added = len(twice) - len(alone) - len((record.name + "2").encode())
            second = replace(record, name=record.name + "2")
            assert added == record_size(second, dtype), record.name  # type: ignore[arg-type]
            assert record_overhead("x", basis_count=127) == 3 and record_overhead("x", basis_count=128) == 4
        entries = parse_bvae(encode_bvae(made, DECODER, latent_dtype=dtype)).header.entries  # type: ignore[arg-type]
        for record, entry in zip(made, entries, strict=True):
            assert entry.length + entry.descriptor_bytes == record_size(record, dtype)  # type: ignore[arg-type]


def _detail_frame() -> bytes:
    from brdfcodec.conventions import NETWORK_INPUT_SHAPE
    from brdfcodec.layers.detail import encode_detail

    return encode_detail(np.zeros(NETWORK_INPUT_SHAPE, dtype=np.float32), 1.0).data


def test_a_file_holds_one_shared_basis_and_provenance_only_when_kept() -> None:
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer

    def on(sha: str, name: str) -> LayeredRecord:
        return LayeredRecord(name, np.zeros(8), np.ones(8), {"effort": 1, "relae": {"mapped": 0.1},
                                                             "edit": {"op": "refine"}},
                             basis=BasisLayer(sha, 0.5, np.ones(3, dtype=np.int8)), compact_sigma=True)

    with pytest.raises(ValueError, match="one shared basis"):
        encode_bvae([on("cd" * 32, "a"), on("ef" * 32, "b")], DECODER)
    parsed = parse_bvae(encode_bvae([on("cd" * 32, "a"), on("cd" * 32, "b")], DECODER))
    assert parsed.header.basis_sha256 == "cd" * 32 and parsed.header.form_count == 1
    assert encode_bvae([on("cd" * 32, "a")], DECODER).count(bytes.fromhex("cd" * 32)) == 1  # stated once
    lean = without_provenance([on("cd" * 32, "a"), LatentRecord("c", np.zeros(8), np.ones(8), {"source_sha256":
                                                                                               "ab" * 32})])
    assert [r.meta for r in lean] == [{"edit": {"op": "refine"}}, {}]  # an edit is the record's meaning, kept
    assert all(set(PROVENANCE_KEYS).isdisjoint(r.meta) for r in lean)


def test_a_corrupt_payload_is_refused_on_opening(tmp_path: Path) -> None:
    path = tmp_path / "lib.bvae"
    write_bvae(path, library(3), DECODER)
    data = bytearray(path.read_bytes())
    data[-70] ^= 0x04  # in a payload: one CRC-32 covers them all
    path.write_bytes(bytes(data))
    with pytest.raises(BvaeChecksumError, match="payload CRC-32"):
        BvaeReader(path)
    with pytest.raises(BvaeChecksumError, match="payload CRC-32"):
        read_bvae(path)
    assert read_header(path).names[0] == "mat-0"  # the header alone is intact


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
    with pytest.raises(BvaeChecksumError, match="payload CRC-32"):
        parse_bvae(bytes(data))
    data[-1] ^= 1
    data[30] ^= 1  # the decoder hash
    with pytest.raises(BvaeChecksumError, match="header CRC-32"):
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
@pytest.mark.slow
def test_fuzz_metadata_json_content(extra: dict) -> None:
    """Arbitrary JSON substituted for metadata fields only raises format errors."""
    def edit(stored: bytes) -> bytes:
        at = _metadata_at(stored)
        block = json.loads(stored[at:])
        block["records"]["mat-0"].update(extra)
        block.update(extra)
        return stored[:at] + json.dumps(block).encode()

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
