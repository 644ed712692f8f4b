"""Property-based fuzzing of the .bvae reader and writer (issue 11).

A short run by default; ``BVAE_FUZZ=long`` (or ``BVAE_FUZZ_EXAMPLES=N``) multiplies the examples, e.g.
``BVAE_FUZZ=long python -m pytest tests/test_bvae_fuzz.py``. Each property covers a class of input the
adversarial pass found defects in: names, metadata types and values, latent sizes, header object counts,
zstandard trailing data. The invariant everywhere: the writer refuses with ``ValueError`` or writes a file
that reads back equal; the reader raises a ``BvaeFormatError`` (or a subclass) or returns records that obey
every rule, never another exception.
"""

from __future__ import annotations

import json
import math
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from brdfcodec.bvae_format import (
    MAGIC,
    MAX_HEADER_CONTAINERS,
    MAX_JSON_INTEGER,
    DecoderReference,
    LatentRecord,
    encode_bvae,
    parse_bvae,
)
from brdfcodec.errors import BvaeFormatError, LatentDimensionError
from brdfcodec.material_names import check_material_name, material_file_path, name_collision_key

DECODER = DecoderReference("ab" * 32, "fuzz-decoder")
SHIPPED = DecoderReference("e1e3ed1e24dc5a8746abbfb9194725e1a9d02808c2e81125c64f3d9e37b39491", "shipped")


def _examples(default: int) -> int:
    if os.environ.get("BVAE_FUZZ_EXAMPLES"):
        return int(os.environ["BVAE_FUZZ_EXAMPLES"])
    return default * 50 if os.environ.get("BVAE_FUZZ") == "long" else default


def fuzz(default: int) -> settings:
    return settings(max_examples=_examples(default), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def raw_file(stored: bytes, payload: bytes, flags: int = 0) -> bytes:
    head = MAGIC + struct.pack("<HHII", 1, 1, flags, len(stored))
    return head + struct.pack("<I", zlib.crc32(stored, zlib.crc32(head))) + stored + payload


def file_with(entry_changes: dict | None = None, dim: int = 2, header_changes: dict | None = None,
              decoder: DecoderReference = DECODER) -> bytes:
    payload = np.array([0.5] * dim + [1.0] * dim, dtype="<f4").tobytes()
    entry = {"name": "a", "kind": "latent", "offset": 0, "length": len(payload), "crc32": zlib.crc32(payload),
             **(entry_changes or {})}
    header = {"format": "bvae", "decoder": {"sha256": decoder.sha256, "name": decoder.name}, "latent_dim": dim,
              "latent_dtype": "float32", "records": [entry], **(header_changes or {})}
    return raw_file(json.dumps(header, ensure_ascii=True).encode(), payload)


def assert_obeys_the_rules(data: bytes) -> None:
    """Parse; a refusal must be a format error, an acceptance must hold only valid names and values."""
    try:
        library = parse_bvae(data)
    except BvaeFormatError:
        return
    keys = set()
    for record in library.records:
        check_material_name(record.name)
        keys.add(name_collision_key(record.name))
        assert np.isfinite(record.mu).all() and (record.sigma > 0).all()
        json.dumps(dict(record.meta), allow_nan=False, ensure_ascii=False).encode("utf-8")
    assert len(keys) == len(library.records)


json_scalars = (st.none() | st.booleans() | st.integers() | st.text()
                | st.floats(allow_nan=True, allow_infinity=True))
json_values = st.recursive(json_scalars, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(), c, max_size=4),
                           max_leaves=12)
defined_meta = st.fixed_dictionaries({}, optional={
    "relae": json_values | st.fixed_dictionaries({}, optional={"mapped": json_scalars, "linear": json_scalars}),
    "source_sha256": json_scalars | st.just("cd" * 32),
    "encoder_sha256": json_scalars,
    "edit": json_values | st.fixed_dictionaries({"op": json_scalars}),
})


@fuzz(200)
@given(st.text(max_size=300))
def test_fuzz_names_on_write(name: str) -> None:
    try:
        record = LatentRecord(name, np.zeros(2), np.ones(2))
    except ValueError:
        return
    assert parse_bvae(encode_bvae([record], DECODER)).header.names == [name]
    folder = Path("out")
    assert material_file_path(folder, name, "binary").parent == folder
    assert ".." not in Path(name).parts and "/" not in name and not name.startswith(".")


@fuzz(200)
@given(st.one_of(st.text(max_size=300), st.integers(), st.none(), st.lists(st.text(max_size=3), max_size=2)))
def test_fuzz_names_on_read(name: object) -> None:
    assert_obeys_the_rules(file_with({"name": name}))


@fuzz(200)
@given(st.text(min_size=1, max_size=6), st.text(min_size=1, max_size=6))
def test_fuzz_name_twins_on_read(first: str, second: str) -> None:
    payload = np.array([0.5, 0.5, 1.0, 1.0], dtype="<f4").tobytes()
    entries = [{"name": n, "kind": "latent", "offset": 16 * i, "length": 16, "crc32": zlib.crc32(payload)}
               for i, n in enumerate((first, second))]
    header = {"format": "bvae", "decoder": {"sha256": DECODER.sha256, "name": "d"}, "latent_dim": 2,
              "latent_dtype": "float32", "records": entries}
    assert_obeys_the_rules(raw_file(json.dumps(header).encode(), payload * 2))


@fuzz(200)
@given(defined_meta, st.dictionaries(st.text(max_size=5), json_values, max_size=3))
def test_fuzz_metadata_write_round_trip(meta: dict, extra: dict) -> None:
    combined = {**extra, **meta}
    try:
        record = LatentRecord("a", np.zeros(2), np.ones(2), combined)
        data = encode_bvae([record], DECODER)
    except ValueError:
        return
    (back,) = parse_bvae(data).records
    assert json.dumps(dict(back.meta), sort_keys=True) == json.dumps(combined, sort_keys=True)


@fuzz(200)
@given(defined_meta | json_values)
def test_fuzz_metadata_on_read(meta: object) -> None:
    # json.dumps writes NaN and infinities as NaN/Infinity, which are not JSON: the reader must refuse them.
    assert_obeys_the_rules(file_with({"meta": meta}))


@fuzz(100)
@given(st.sampled_from(["1e400", "-1e999", "1e308", "9007199254740991", "9007199254740992", "-0", "0.0e0",
                        "123456789012345678901234567890", "1E+2", "NaN", "Infinity", "-Infinity", "1e-400"]))
def test_fuzz_number_extremes(number: str) -> None:
    data = file_with({"meta": {"x": 0}})
    data = raw_file(data[24:-16].replace(b'"x": 0', f'"x": {number}'.encode()), data[-16:])
    try:
        (record,) = parse_bvae(data).records
    except BvaeFormatError:
        return
    value = record.meta["x"]
    assert math.isfinite(value)
    assert not isinstance(value, int) or abs(value) <= MAX_JSON_INTEGER


@fuzz(60)
@given(st.integers(-2, 2100))
def test_fuzz_latent_sizes(dim: int) -> None:
    size = max(dim, 1)
    payload = np.array([0.0] * size + [1.0] * size, dtype="<f4").tobytes()
    entry = {"name": "a", "kind": "latent", "offset": 0, "length": len(payload), "crc32": zlib.crc32(payload)}
    header = {"format": "bvae", "decoder": {"sha256": SHIPPED.sha256, "name": "d"}, "latent_dim": dim,
              "latent_dtype": "float32", "records": [entry]}
    data = raw_file(json.dumps(header).encode(), payload)
    try:
        library = parse_bvae(data)
    except BvaeFormatError:
        assert not 1 <= dim <= 1024
        return
    assert 1 <= dim <= 1024 and library.header.latent_dim == dim
    if dim != 8:  # opening it for decoding with the shipped (8-D) decoder must refuse it, with a typed error
        with pytest.raises(LatentDimensionError):
            _shipped_decoder().check(library.header, "<fuzz>")


_DECODER_CACHE: list = []


def _shipped_decoder():  # noqa: ANN202 - loaded once for the whole run
    if not _DECODER_CACHE:
        from brdfcodec.codec import BrdfDecoder

        _DECODER_CACHE.append(BrdfDecoder())
    return _DECODER_CACHE[0]


@fuzz(40)
@given(st.integers(0, 2 * MAX_HEADER_CONTAINERS), st.sampled_from([b"[]", b"{}", b"[[]]"]),
       st.booleans())
def test_fuzz_header_object_counts(count: int, item: bytes, compress: bool) -> None:
    base = file_with()
    stored = base[24:-16]
    filler = b"[" + b",".join([item] * count) + b"]"
    text = stored.replace(b'"format": "bvae"', b'"format": "bvae", "x": ' + filler)
    # The header object, decoder, records, the entry, the list "x", and what each item holds.
    containers = 5 + count * (item.count(b"[") + item.count(b"{"))
    flags = 0
    if compress:
        import zstandard

        text, flags = zstandard.ZstdCompressor(level=1, write_content_size=True).compress(text), 1
    if len(text) > (1 << 20):
        return
    try:
        parse_bvae(raw_file(text, base[-16:], flags))
    except BvaeFormatError as error:
        assert containers > MAX_HEADER_CONTAINERS, error
        assert "JSON objects and arrays" in str(error) or "content size" in str(error), error
        return
    assert containers <= MAX_HEADER_CONTAINERS


@fuzz(150)
@given(st.binary(min_size=1, max_size=64), st.booleans())
def test_fuzz_zstd_trailing_data(extra: bytes, as_frame: bool) -> None:
    import zstandard

    data = encode_bvae([LatentRecord("a", np.zeros(2), np.ones(2))], DECODER, compress_header=True)
    length = struct.unpack_from("<I", data, 16)[0]
    frame, payload = data[24 : 24 + length], data[24 + length :]
    tail = zstandard.ZstdCompressor(write_content_size=True).compress(extra) if as_frame else extra
    with pytest.raises(BvaeFormatError):
        parse_bvae(raw_file(frame + tail, payload, flags=1))


@fuzz(300)
@given(st.binary(max_size=512))
def test_fuzz_arbitrary_header_bytes_under_a_valid_crc(stored: bytes) -> None:
    assert_obeys_the_rules(raw_file(stored, b""))
