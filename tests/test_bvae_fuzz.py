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
from pathlib import Path

import numpy as np
import pytest
from bvae_bytes import bytes_writer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from brdfcodec.errors import BvaeFormatError, LatentDimensionError
from brdfcodec.format.bvae import (
    MAX_HEADER_BYTES,
    MAX_HEADER_CONTAINERS,
    MAX_JSON_INTEGER,
    DecoderReference,
    LatentRecord,
    encode_bvae,
    parse_bvae,
)
from brdfcodec.format.material_names import check_material_name, material_file_path, name_collision_key
from brdfcodec.models.manifest import load_manifest
from brdfcodec.models.registry import default_model_folder

DECODER = DecoderReference("ab" * 32, "fuzz-decoder")
SHIPPED = DecoderReference(load_manifest(default_model_folder()).decoder_sha256, "shipped")


def _examples(default: int) -> int:
    if os.environ.get("BVAE_FUZZ_EXAMPLES"):
        return int(os.environ["BVAE_FUZZ_EXAMPLES"])
    return default * 50 if os.environ.get("BVAE_FUZZ") == "long" else default


def fuzz(default: int) -> settings:
    return settings(max_examples=_examples(default), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def raw_file(stored: bytes, payload: bytes, flags: int = 0) -> bytes:
    """Preamble (format 2.0, valid header CRC), header and payload, by hand."""
    return bytes_writer.assemble(stored, payload, flags=flags)


def file_with(name: str | bytes = "a", metadata: bytes = b"", dim: int = 2,
              decoder: DecoderReference = DECODER) -> bytes:
    """A file of one latent record by hand: any name bytes, any metadata block (JSON text)."""
    payload = np.array([0.5] * max(dim, 1) + [1.0] * max(dim, 1), dtype="<f4").tobytes()
    raw = name.encode("utf-8", "surrogatepass") if isinstance(name, str) else name
    stored = bytes_writer.header([bytes_writer.latent_form()], [bytes_writer.descriptor(raw, 0)], payload,
                                 dim=dim % 65536, decoder=decoder.sha256, metadata=metadata)
    return raw_file(stored, payload)


def meta_text(meta: object) -> bytes:
    """A metadata block giving record "a" ``meta`` (NaN and infinities written as Python's json writes them)."""
    return json.dumps({"records": {"a": meta}}).encode()


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
@given(st.one_of(st.text(max_size=300), st.binary(max_size=300)))
def test_fuzz_names_on_read(name: str | bytes) -> None:
    assert_obeys_the_rules(file_with(name))


@fuzz(200)
@given(st.text(min_size=1, max_size=6), st.text(min_size=1, max_size=6))
def test_fuzz_name_twins_on_read(first: str, second: str) -> None:
    payload = np.array([0.5, 0.5, 1.0, 1.0], dtype="<f4").tobytes()
    names = [bytes_writer.descriptor(n.encode("utf-8", "surrogatepass"), 0) for n in (first, second)]
    stored = bytes_writer.header([bytes_writer.latent_form()], names, payload * 2)
    assert_obeys_the_rules(raw_file(stored, payload * 2))


@fuzz(200)
@given(defined_meta, st.dictionaries(st.text(max_size=5), json_values, max_size=3))
@pytest.mark.slow
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
    assert_obeys_the_rules(file_with(metadata=meta_text(meta)))


@fuzz(100)
@given(st.sampled_from(["1e400", "-1e999", "1e308", "9007199254740991", "9007199254740992", "-0", "0.0e0",
                        "123456789012345678901234567890", "1E+2", "NaN", "Infinity", "-Infinity", "1e-400"]))
def test_fuzz_number_extremes(number: str) -> None:
    data = file_with(metadata=meta_text({"x": 0}).replace(b'"x": 0', f'"x": {number}'.encode()))
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
    data = file_with(dim=dim, decoder=SHIPPED)
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
@pytest.mark.slow
def test_fuzz_header_object_counts(count: int, item: bytes, compress: bool) -> None:
    base = file_with()
    index = base[24:-16]
    filler = b"[" + b",".join([item] * count) + b"]"
    text = b'{"records": {"a": {}}, "x": ' + filler + b"}"
    # The metadata object, records, the record's, the list "x", and what each item holds.
    containers = 4 + count * (item.count(b"[") + item.count(b"{"))
    flags = 0
    if compress:
        import zstandard

        text, flags = zstandard.ZstdCompressor(level=1, write_content_size=True).compress(text), 1
    if len(text) > MAX_HEADER_BYTES:
        return
    try:
        parse_bvae(raw_file(index + text, base[-16:], flags))
    except BvaeFormatError as error:
        assert containers > MAX_HEADER_CONTAINERS, error
        assert "JSON objects and arrays" in str(error) or "content size" in str(error), error
        return
    assert containers <= MAX_HEADER_CONTAINERS


@fuzz(150)
@given(st.binary(min_size=1, max_size=64), st.booleans())
def test_fuzz_zstd_trailing_data(extra: bytes, as_frame: bool) -> None:
    import zstandard

    data = encode_bvae([LatentRecord("a", np.zeros(2), np.ones(2), {"effort": 1})], DECODER, compress_header=True)
    length = struct.unpack_from("<I", data, 16)[0]
    stored, payload = data[24 : 24 + length], data[24 + length :]
    tail = zstandard.ZstdCompressor(write_content_size=True).compress(extra) if as_frame else extra
    with pytest.raises(BvaeFormatError):
        parse_bvae(raw_file(stored + tail, payload, flags=1))
    assert parse_bvae(raw_file(stored, payload, flags=1)).header.names == ["a"]  # the frame alone reads


@fuzz(300)
@given(st.binary(max_size=512))
def test_fuzz_arbitrary_header_bytes_under_a_valid_crc(stored: bytes) -> None:
    assert_obeys_the_rules(raw_file(stored, b""))
