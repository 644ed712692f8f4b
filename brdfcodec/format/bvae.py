"""The ``.bvae`` file format: read, write and inspect (``spec/bvae-format.md``).

A ``.bvae`` file holds the latent codes of one material or of a library of
materials, and the SHA-256 of the decoder that turns them back into BRDF
tables. This module does not import torch: inspecting a file (``bvae info``)
is instant, and a file can be checked on a machine without a model.

Layout (format 2.1, little-endian)::

    preamble  24 bytes   magic, version, flags, header length, header CRC-32
    header    N bytes    binary: decoder SHA-256, latent size and dtype, the shared
                         basis' SHA-256 (once), the form table (how records store
                         μ, σ and their layers, once per form), the record index
                         (name, form, per-record numbers), the payloads' CRC-32;
                         then an optional JSON metadata block (provenance, edits)
    records   ...        raw payloads, contiguous, in index order; the file
                         ends exactly where the last record ends

Every byte is covered by a CRC-32: the preamble and header by the header CRC,
the payloads by the payload CRC in the header. A record's descriptor holds
only its name and what varies between records (:func:`record_overhead`), so a
file costs little more than its payloads and names.
"""

from __future__ import annotations

import functools
import io
import json
import math
import os
import re
import struct
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, BinaryIO, Literal

import numpy as np

from brdfcodec.errors import BvaeChecksumError, BvaeFormatError, UnsupportedVersionError
from brdfcodec.format.layered_record import (
    UnsupportedLayerError,
    latent_values_stored,
    layered_from_payload,
    layers_entry,
    layers_length,
)
from brdfcodec.format.material_names import MAX_NAME_LENGTH as MAX_NAME_LENGTH  # re-exported
from brdfcodec.format.material_names import check_material_name, name_collision_key
from brdfcodec.format.records import MAX_LATENT_DIM as MAX_LATENT_DIM  # re-exported
from brdfcodec.format.records import GraftRecord, LatentRecord, meta_problem
from brdfcodec.io.atomic import atomic_output
from brdfcodec.version import __version__

__all__ = [
    "FORMAT_MAJOR",
    "FORMAT_MINOR",
    "MAGIC",
    "MAX_HEADER_BYTES",
    "PROVENANCE_KEYS",
    "BvaeHeader",
    "BvaeReader",
    "DecoderReference",
    "GraftRecord",
    "LatentRecord",
    "ParsedBvae",
    "Record",
    "RecordEntry",
    "encode_bvae",
    "parse_bvae",
    "descriptor_size",
    "record_overhead",
    "record_size",
    "read_bvae",
    "read_header",
    "without_provenance",
    "write_bvae",
]

#: First 8 bytes of every ``.bvae`` file (a non-ASCII byte, the name, CR LF, EOF: catches text-mode transfers).
MAGIC = b"\x89BVAE\r\n\x1a"
#: Major version written and read; a file of another major version (the development format 1.x too) is refused.
#: 2.0 (issue 40): a binary header and index, file-level facts stated once, metadata opt-in in a JSON block.
FORMAT_MAJOR = 2
#: Minor version written; readers accept any minor version of their major version.
#: 2.1: basis-only layered records (``layers.mu`` and ``layers.sigma`` ``"none"``: no latent, spec §4.6).
FORMAT_MINOR = 1
#: Largest stored header (binary index and stored metadata block), in bytes.
MAX_HEADER_BYTES = 1 << 24
#: Largest metadata block, decompressed, in bytes.
MAX_HEADER_JSON_BYTES = 16 << 20
#: Largest number of records in one file.
MAX_RECORDS = 65536
#: Most JSON objects and arrays (nested ones included) a header may hold: bounds the work of parsing.
MAX_HEADER_CONTAINERS = 1 << 19
#: Deepest nesting of JSON objects and arrays in a header.
MAX_HEADER_DEPTH = 64
#: Largest magnitude of a JSON integer in a header (I-JSON, RFC 7493: exact in binary64).
MAX_JSON_INTEGER = (1 << 53) - 1

#: Flag bit 0: the header's metadata block is a zstandard frame.
FLAG_METADATA_ZSTD = 1 << 0
#: Flag bit 1: the header names the shared basis of the file's basis layers.
FLAG_BASIS = 1 << 1
KNOWN_FLAGS = FLAG_METADATA_ZSTD | FLAG_BASIS
#: Longest varint (LEB128) in a header, in bytes: values below 2^28.
_VARINT_MAX_BYTES = 4

_PREAMBLE = struct.Struct("<8sHHIII")
PREAMBLE_SIZE = _PREAMBLE.size  # 24
_CRC_COVERED_PREAMBLE = PREAMBLE_SIZE - 4
_ZSTD_LEVEL = 19
#: Headers longer than this (in JSON bytes) are compressed at a faster level (§3.1): level 19 runs at ~0.3 MB/s.
_ZSTD_FAST_ABOVE = 1 << 20
_ZSTD_FAST_LEVEL = 3

LatentDtype = Literal["float32", "float16"]
_DTYPES: dict[str, np.dtype] = {"float32": np.dtype("<f4"), "float16": np.dtype("<f2")}
_DTYPE_CODES = {"float32": 0, "float16": 1}
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_RECORD_KINDS = ("latent", "graft", "layered")  # "layered": brdfcodec.format.layered_record.LayeredRecord


@dataclass(frozen=True)
class DecoderReference:
    """The decoder a file's latents belong to.

    Attributes
    ----------
    sha256 : str
        Lower-case hex SHA-256 of the decoder weight file (``decoder.safetensors``).
    name : str
        Readable model name (informative; the hash decides).
    """

    sha256: str
    name: str

    def __post_init__(self) -> None:
        if not isinstance(self.sha256, str) or not _SHA256.match(self.sha256):
            raise ValueError(f"decoder SHA-256 must be 64 lower-case hex digits, got {self.sha256!r}")
        if not isinstance(self.name, str):
            raise ValueError(f"decoder name must be a string, got {self.name!r}")


Record = LatentRecord | GraftRecord


@dataclass(frozen=True)
class RecordEntry:
    """One record as the header's index describes it (no payload read).

    ``offset`` and ``length`` are derived from the form and the per-record
    numbers (§3.3); ``layers`` is the layered record's description with the
    file-level parts filled in (the basis' SHA-256, the form's ``first``,
    ``project``, ``mu``, ``sigma``, the detail dtype); ``descriptor_bytes``
    is what the index spends on the record beyond its name's bytes.
    """

    name: str
    kind: str
    offset: int
    length: int
    meta: Mapping[str, Any]
    graft_dims: tuple[int, ...] = ()
    layers: Mapping[str, Any] | None = None  # kind "layered" only (brdfcodec.format.layered_record)
    descriptor_bytes: int = 0


@dataclass(frozen=True)
class _Form:
    """An entry of the form table as read: a kind, graft dimensions, or a layered record's fixed layer fields."""

    kind: str
    graft_dims: tuple[int, ...]
    layers: Mapping[str, Any] | None


@dataclass(frozen=True)
class BvaeHeader:
    """Everything a ``.bvae`` file says before its records.

    Attributes
    ----------
    major, minor : int
        Format version of the file.
    flags : int
        Flag bits (bit 0: header compressed with zstandard).
    decoder : DecoderReference
    latent_dim : int
    latent_dtype : {"float32", "float16"}
    entries : tuple of RecordEntry
        The index, in file order.
    created_by : str
        Writer (informative).
    header_bytes : int
        Stored size of the header (index and metadata block).
    records_offset : int
        File offset of the first record.
    file_size : int
        Total size of the file, in bytes.
    basis_sha256 : str or None
        The shared basis every basis layer of the file is on (None: no basis layer).
    payload_crc32 : int
        CRC-32 of all the payloads.
    form_count : int
        Entries of the form table.
    """

    major: int
    minor: int
    flags: int
    decoder: DecoderReference
    latent_dim: int
    latent_dtype: LatentDtype
    entries: tuple[RecordEntry, ...]
    created_by: str
    header_bytes: int
    records_offset: int
    file_size: int
    basis_sha256: str | None = None
    payload_crc32: int = 0
    form_count: int = 1

    @property
    def names(self) -> list[str]:
        """Material names in file order."""
        return [entry.name for entry in self.entries]

    @functools.cached_property
    def positions(self) -> Mapping[str, int]:
        """Position of each material in the index, by name (built once: lookups are O(1))."""
        return {entry.name: i for i, entry in enumerate(self.entries)}

    def entry(self, name: str) -> RecordEntry:
        """Index entry of a material; ``KeyError`` naming the available ones if absent."""
        position = self.positions.get(name)
        if position is None:
            shown = ", ".join(self.names[:20]) + (", …" if len(self.entries) > 20 else "")
            raise KeyError(f"no material {name!r} in the file; it holds: {shown}")
        return self.entries[position]


@dataclass(frozen=True)
class ParsedBvae:
    """What :func:`parse_bvae` and :func:`read_bvae` return: a file's header and every record, parsed.

    A plain parse result with no decoder attached; the one library class
    users open to decode materials is :class:`brdfcodec.codec.MaterialLibrary`.
    """

    header: BvaeHeader
    records: tuple[Record, ...]

    def record(self, name: str) -> Record:
        """The record of a material (``KeyError`` naming the available ones if absent)."""
        self.header.entry(name)  # a descriptive KeyError if absent
        return self.records[self.header.positions[name]]


#: Former name of :class:`ParsedBvae`, kept so that existing imports work.
BvaeLibrary = ParsedBvae


# --------------------------------------------------------------------------- writing


#: Metadata keys (§5) that describe how a record was made and measured: opt-in (``bvae compress --provenance``).
PROVENANCE_KEYS = ("source_sha256", "source_kind", "relae", "encoder_sha256", "effort", "rate")


def without_provenance(records: Sequence[Record]) -> list[Record]:
    """The records without the metadata of :data:`PROVENANCE_KEYS` (other keys, such as ``edit``, are kept).

    A writer that was not asked for provenance stores none (format 2.0, §5): the file then costs the names,
    the descriptors and the payloads.
    """
    out: list[Record] = []
    for record in records:
        kept = {key: value for key, value in record.meta.items() if key not in PROVENANCE_KEYS}
        out.append(record if len(kept) == len(record.meta) else replace(record, meta=kept))
    return out


def canonical_json(value: Any) -> bytes:
    """The canonical UTF-8 JSON text of a header (§3.1): sorted keys, no white space, shortest numbers.

    Raises
    ------
    ValueError
        The value holds something JSON cannot carry in a ``.bvae`` header:
        NaN or infinity, an integer beyond ±(2⁵³ − 1), a lone surrogate, a
        duplicate key after conversion to text, or a non-JSON type.
    """
    try:
        text = json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
        data = text.encode("utf-8")
    except (TypeError, ValueError, UnicodeEncodeError, RecursionError) as error:
        raise ValueError(f"record metadata must be JSON values (finite numbers, valid Unicode): {error}") from None
    outside_strings = _check_json_structure(data, ValueError)  # keys are unique: they come from dicts
    for match in _LONG_INTEGER.finditer(outside_strings):
        if abs(int(match.group())) > MAX_JSON_INTEGER:
            raise ValueError(f"record metadata holds the integer {match.group()[:40].decode()}, beyond ±(2^53 - 1)")
    return data


def _check_json_structure(data: bytes, fail: Any) -> bytes:
    """The bounds of §3 on JSON objects and arrays (their number, their nesting); returns the text without strings."""
    # Outside strings, brackets are exactly the containers: count them and their nesting before parsing.
    outside_strings = _JSON_STRING.sub(b'""', data)
    structure = np.frombuffer(outside_strings, dtype=np.uint8)
    opens = (structure == ord("{")) | (structure == ord("["))
    containers = int(np.count_nonzero(opens))
    if containers > MAX_HEADER_CONTAINERS:
        raise fail(f"header holds {containers} JSON objects and arrays, more than {MAX_HEADER_CONTAINERS}")
    closes = (structure == ord("}")) | (structure == ord("]"))
    depth = int(np.cumsum(opens.astype(np.int64) - closes).max(initial=0))
    if depth > MAX_HEADER_DEPTH:
        raise fail(f"header JSON is nested {depth} levels deep, more than {MAX_HEADER_DEPTH}")
    return outside_strings


def _check_json_text(data: bytes, fail: Any) -> Any:
    """Parse header JSON under the rules and bounds of §3 (raises ``fail(message)`` on any breach)."""
    _check_json_structure(data, fail)
    try:
        value = json.loads(
            data.decode("utf-8"),
            parse_constant=_reject_constant,
            parse_float=_finite_float,
            parse_int=_exact_int,
            object_pairs_hook=_unique_keys,
        )
    except (UnicodeDecodeError, ValueError, RecursionError) as error:
        raise fail(f"header is not valid UTF-8 JSON ({error})") from None
    try:  # lone surrogates ("\ud800") are valid JSON escapes but not Unicode text
        json.dumps(value, ensure_ascii=False).encode("utf-8")
    except UnicodeEncodeError:
        raise fail("header holds a lone surrogate escape (not Unicode text)") from None
    return value


#: An integer token of 16 digits or more (2^53 has 16): the only ones that can exceed ±(2^53 - 1).
_LONG_INTEGER = re.compile(rb"(?<![0-9.eE+-])-?[0-9]{16,}(?![0-9.eE])")
#: A JSON string (with escapes): its content is removed before counting brackets.
_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.S)


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:40]} overflows binary64 (infinity is not allowed)")
    return value


def _exact_int(text: str) -> int:
    value = int(text)
    if abs(value) > MAX_JSON_INTEGER:
        raise ValueError(f"integer {text[:40]} exceeds ±(2^53 - 1)")
    return value


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    result = dict(pairs)
    if len(result) != len(pairs):
        keys = [k for k, _ in pairs]
        repeated = sorted({k for k in keys if keys.count(k) > 1})
        raise ValueError(f"duplicate key {repeated[0]!r} in a JSON object")
    return result


def _varint(value: int) -> bytes:
    """Unsigned LEB128 (§2.1): 7 bits a byte, lowest group first, the high bit set on every byte but the last."""
    if not 0 <= value < 1 << (7 * _VARINT_MAX_BYTES):
        raise ValueError(f"{value!r} cannot be stored as a .bvae varint (0 to 2^28 - 1)")
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _varint_size(value: int) -> int:
    return max(1, (int(value).bit_length() + 6) // 7)


def record_overhead(name: str, *, basis_count: int | None = None, detail_bytes: int | None = None) -> int:
    """Bytes a record's descriptor takes in the index beyond its name's UTF-8 bytes (§3.3).

    This is what ``--bytes N`` counts besides the payload: the name's length
    (a varint), the form byte and, by the record's form, the basis
    coefficient count (a varint) and the detail layer's step (8 bytes) and
    length (a varint). File-level parts (preamble, header fields, form
    table, CRC-32s) belong to no record.

    Parameters
    ----------
    name : str
        The record's name.
    basis_count : int, optional
        Basis coefficients, when the record has a basis layer.
    detail_bytes : int, optional
        Bytes of the detail layer, when the record has one.

    Returns
    -------
    int
    """
    size = _varint_size(len(name.encode("utf-8"))) + 1
    if basis_count is not None:
        size += _varint_size(basis_count)
    if detail_bytes is not None:
        size += 8 + _varint_size(detail_bytes)
    return size


def descriptor_size(record: Record) -> int:
    """:func:`record_overhead` of a record: its descriptor's bytes beyond its name's."""
    basis, detail = getattr(record, "basis", None), getattr(record, "detail", None)
    return record_overhead(record.name, basis_count=None if basis is None else basis.count,
                           detail_bytes=None if detail is None else detail.nbytes)


def record_size(record: Record, latent_dtype: LatentDtype = "float32") -> int:
    """What a record adds to a file beyond its name's UTF-8 bytes: its payload plus :func:`descriptor_size`."""
    return len(_payload(record, _DTYPES[latent_dtype])) + descriptor_size(record)


def _payload(record: Record, dtype: np.dtype) -> bytes:
    payload = record.payload_values().astype(dtype).tobytes()
    if record.kind == "layered":  # layered records (brdfcodec.format.layered_record): layer bytes follow the values
        payload += record.layer_bytes()  # type: ignore[union-attr]
    return payload


#: Codes of the form table (§3.2): record kinds, how μ and σ are stored, the detail layer's coefficient type.
_KIND_CODES = {"latent": 0, "graft": 1, "layered": 2}
_MU_CODES: dict[str | None, int] = {None: 0, "int8": 1, "int8-fixed": 2, "none": 3}
_SIGMA_CODES: dict[str | None, int] = {None: 0, "log2-u8": 1, "log2-u8-shared": 2, "none": 3}
_DETAIL_CODES = {"int16": 0, "int32": 1}  # transform "dct3-ycc", the only one
_LAYER_BASIS, _LAYER_DETAIL = 1, 2
#: Most entries of a file's form table (its count is one byte).
MAX_FORMS = 255


def _form_of(record: Record) -> tuple[Any, ...]:
    """A record's form (§3.2): what the form table states once for every record that shares it."""
    if isinstance(record, GraftRecord):
        return ("graft", tuple(record.graft_dims))
    if record.kind != "layered":
        return ("latent",)
    layers = layers_entry(record)  # type: ignore[arg-type]
    basis, detail = layers.get("basis"), layers.get("detail")
    return ("layered", layers.get("mu"), layers.get("sigma"),
            None if basis is None else (int(basis.get("first", 0)), int(basis.get("project", 0))),
            None if detail is None else str(detail["dtype"]))


def _form_bytes(form: tuple[Any, ...]) -> bytes:
    kind = form[0]
    out = bytes([_KIND_CODES[kind]])
    if kind == "graft":
        return out + _varint(len(form[1])) + b"".join(_varint(d) for d in form[1])
    if kind == "layered":
        _, mu, sigma, basis, detail = form
        layers = (_LAYER_BASIS if basis is not None else 0) | (_LAYER_DETAIL if detail is not None else 0)
        out += bytes([_MU_CODES[mu], _SIGMA_CODES[sigma], layers])
        if basis is not None:
            out += _varint(basis[0]) + _varint(basis[1])
        if detail is not None:
            out += bytes([_DETAIL_CODES[detail]])
    return out


def encode_bvae(
    records: Sequence[Record],
    decoder: DecoderReference,
    *,
    latent_dtype: LatentDtype = "float32",
    compress_header: bool | None = None,
) -> bytes:
    """Serialise records to the bytes of a ``.bvae`` file (format 2.1).

    Parameters
    ----------
    records : sequence of LatentRecord, GraftRecord or LayeredRecord
        At least one; names unique; all of the same latent dimension; every
        basis layer on the same shared basis. Each record's ``meta`` is
        written as given (the metadata block, §5): a record without ``meta``
        costs its name, its descriptor and its payload only.
    decoder : DecoderReference
        The decoder the latents belong to. Its name is written only when the
        file has a metadata block (informative; the hash decides).
    latent_dtype : {"float32", "float16"}, default "float32"
        Storage of the latent values. float16 halves the payload; values are
        rounded to nearest (|values| above 65504 are refused).
    compress_header : bool, optional
        Compress the metadata block with zstandard. By default it is
        compressed when that makes it smaller.

    Returns
    -------
    bytes
        The file content. The same input always gives the same bytes.
    """
    if latent_dtype not in _DTYPES:
        raise ValueError(f"latent_dtype must be one of {sorted(_DTYPES)}, got {latent_dtype!r}")
    records = list(records)
    if not records:
        raise ValueError("a .bvae file needs at least one record")
    if len(records) > MAX_RECORDS:
        raise ValueError(f"a .bvae file holds at most {MAX_RECORDS} records, got {len(records)}")
    seen: dict[str, str] = {}
    for record in records:
        key = name_collision_key(record.name)
        if key in seen:
            raise ValueError(
                f"material names must be unique in a file, also ignoring case: {seen[key]!r} and {record.name!r}"
            )
        seen[key] = record.name
    latent_dim = records[0].latent_dim
    if any(r.latent_dim != latent_dim for r in records):
        raise ValueError("all records of a file must have the same latent dimension")
    layers = [getattr(r, "basis", None) for r in records]
    bases = sorted({layer.sha256 for layer in layers if layer is not None})
    if len(bases) > 1:
        raise ValueError(f"a file holds the basis layers of one shared basis; these records use {len(bases)}")
    dtype = _DTYPES[latent_dtype]
    forms: dict[tuple[Any, ...], int] = {}
    descriptors: list[bytes] = []
    payloads: list[bytes] = []
    metadata: dict[str, Any] = {}
    for record in records:
        values = record.payload_values()
        if latent_dtype == "float16" and np.abs(values).max(initial=0.0) > np.finfo(np.float16).max:
            raise ValueError(f"{record.name}: latent values exceed the float16 range; store them as float32")
        payload = _payload(record, dtype)
        form = _form_of(record)
        if form not in forms:
            if len(forms) == MAX_FORMS:
                raise ValueError(f"the records need more than {MAX_FORMS} record forms; split the library")
            forms[form] = len(forms)
        name = record.name.encode("utf-8")
        descriptor = _varint(len(name)) + name + bytes([forms[form]])
        basis, detail = getattr(record, "basis", None), getattr(record, "detail", None)
        if basis is not None:
            descriptor += _varint(basis.count)
        if detail is not None:
            descriptor += struct.pack("<d", detail.step) + _varint(detail.nbytes)
        descriptors.append(descriptor)
        payloads.append(payload)
        if record.meta:
            metadata[record.name] = dict(record.meta)
    data = b"".join(payloads)
    flags = FLAG_BASIS if bases else 0
    header = bytearray(bytes.fromhex(decoder.sha256) + struct.pack("<HB", latent_dim, _DTYPE_CODES[latent_dtype]))
    if bases:
        header += bytes.fromhex(bases[0])
    header += bytes([len(forms)]) + b"".join(_form_bytes(f) for f in forms)
    header += _varint(len(records)) + b"".join(descriptors) + struct.pack("<I", zlib.crc32(data))
    if metadata:
        block = {"created_by": f"brdfcodec {__version__}", "decoder_name": decoder.name, "records": metadata}
        stored = canonical_json(block)
        if len(stored) > MAX_HEADER_JSON_BYTES:
            raise ValueError(f"metadata of {len(stored)} bytes exceeds {MAX_HEADER_JSON_BYTES}; split the library")
        if compress_header is not False:
            import zstandard

            level = _ZSTD_LEVEL if len(stored) <= _ZSTD_FAST_ABOVE else _ZSTD_FAST_LEVEL
            packed = zstandard.ZstdCompressor(level=level, write_content_size=True).compress(stored)
            if compress_header or len(packed) < len(stored):
                stored, flags = packed, flags | FLAG_METADATA_ZSTD
        header += stored
    if len(header) > MAX_HEADER_BYTES:
        raise ValueError(f"stored header of {len(header)} bytes exceeds {MAX_HEADER_BYTES}; split the library")
    head = _PREAMBLE.pack(MAGIC, FORMAT_MAJOR, FORMAT_MINOR, flags, len(header), 0)[:_CRC_COVERED_PREAMBLE]
    crc = zlib.crc32(header, zlib.crc32(head))
    return head + struct.pack("<I", crc) + bytes(header) + data


def write_bvae(
    path: str | os.PathLike[str],
    records: Sequence[Record],
    decoder: DecoderReference,
    *,
    latent_dtype: LatentDtype = "float32",
    overwrite: bool = False,
) -> int:
    """Write a ``.bvae`` file atomically (see :func:`encode_bvae`).

    Returns
    -------
    int
        Size of the written file, in bytes.

    Raises
    ------
    FileExistsError
        ``path`` exists and ``overwrite`` is false.
    """
    data = encode_bvae(records, decoder, latent_dtype=latent_dtype)
    with atomic_output(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)
    return len(data)


# --------------------------------------------------------------------------- reading


def _fail(path: str, problem: str) -> BvaeFormatError:
    return BvaeFormatError(path, problem)


def _parse_preamble(path: str, preamble: bytes, file_size: int) -> tuple[int, int, int, int, int]:
    if len(preamble) < len(MAGIC) or preamble[: len(MAGIC)] != MAGIC:
        raise _fail(path, "not a .bvae file (wrong magic number)")
    if len(preamble) < PREAMBLE_SIZE:
        raise _fail(path, f"truncated: {file_size} bytes, shorter than the {PREAMBLE_SIZE}-byte preamble")
    _, major, minor, flags, header_length, crc = _PREAMBLE.unpack(preamble)
    if major != FORMAT_MAJOR:
        raise UnsupportedVersionError(
            path, f"format version {major}.{minor} is not supported by this reader (version {FORMAT_MAJOR}.x); "
            + ("files of the development format 1.x are not read: re-create the file with this version"
               if major < FORMAT_MAJOR else "upgrade brdfcodec, or re-create the file with this version")
        )
    if header_length > MAX_HEADER_BYTES:
        raise _fail(path, f"header length {header_length} exceeds the maximum of {MAX_HEADER_BYTES} bytes")
    if PREAMBLE_SIZE + header_length > file_size:
        needed = PREAMBLE_SIZE + header_length
        raise _fail(path, f"truncated: the header needs {needed} bytes, the file has {file_size}")
    return major, minor, flags, header_length, crc


def _decompress_header(path: str, stored: bytes) -> bytes:
    """The one zstandard frame of a compressed metadata block (§5): declared size within the limit, nothing after."""
    import zstandard

    try:
        params = zstandard.get_frame_parameters(stored)
        if params.content_size <= 0 or params.content_size > MAX_HEADER_JSON_BYTES:
            raise _fail(path, "compressed metadata does not declare a content size within the limit")
        raw = zstandard.ZstdDecompressor().decompress(stored, max_output_size=MAX_HEADER_JSON_BYTES)
        stream = zstandard.ZstdDecompressor().decompressobj()
        stream.decompress(stored)  # bounded: the frame just decompressed within the limit
    except zstandard.ZstdError as error:
        raise _fail(path, f"compressed metadata cannot be decompressed ({error})") from None
    if stream.unused_data:
        raise _fail(path, f"{len(stream.unused_data)} bytes after the compressed metadata's zstandard frame")
    return raw


def _check_header_crc(path: str, preamble: bytes, stored: bytes, flags: int, crc: int) -> None:
    if zlib.crc32(stored, zlib.crc32(preamble[:_CRC_COVERED_PREAMBLE])) != crc:
        raise BvaeChecksumError(path, "header CRC-32 mismatch: the file is corrupt (re-create or re-download it)")
    if flags & ~KNOWN_FLAGS:  # after the CRC: a flipped bit is corruption, a set bit under a good CRC a new feature
        raise UnsupportedVersionError(
            path, f"flag bits 0x{flags & ~KNOWN_FLAGS:08x} name features this reader does not know; upgrade brdfcodec"
        )


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not allowed in a .bvae header")


class _Cursor:
    """Reads the binary header field by field; running past its end is a malformed (truncated) header."""

    def __init__(self, path: str, data: bytes) -> None:
        self.path, self.data, self.at = path, data, 0

    def take(self, count: int, what: str) -> bytes:
        if self.at + count > len(self.data):
            raise _fail(self.path, f"header ends inside {what}")
        self.at += count
        return self.data[self.at - count : self.at]

    def u8(self, what: str) -> int:
        return self.take(1, what)[0]

    def varint(self, what: str) -> int:
        value = 0
        for i in range(_VARINT_MAX_BYTES):
            byte = self.u8(what)
            value |= (byte & 0x7F) << (7 * i)
            if not byte & 0x80:
                if i and not byte:
                    raise _fail(self.path, f"{what} is a varint with a superfluous zero byte (not minimal)")
                return value
        raise _fail(self.path, f"{what} is a varint longer than {_VARINT_MAX_BYTES} bytes")


def _parse_form(path: str, cursor: _Cursor, i: int, latent_dim: int, basis_sha: str | None) -> _Form:
    where = f"record form {i}"
    code = cursor.u8(f"{where}'s kind")
    kinds = {v: k for k, v in _KIND_CODES.items()}
    if code not in kinds:
        raise UnsupportedVersionError(path, f"{where} has record kind {code}, unknown to this reader; "
                                      "upgrade brdfcodec")
    kind = kinds[code]
    if kind == "graft":
        count = cursor.varint(f"{where}'s graft dimension count")
        dims = [cursor.varint(f"{where}'s graft dimensions") for _ in range(min(count, latent_dim + 1))]
        if not 1 <= count <= latent_dim or len(set(dims)) != len(dims) or not all(d < latent_dim for d in dims):
            raise _fail(path, f"{where} has invalid graft dimensions ({count}: {dims[:8]})")
        return _Form("graft", tuple(dims), None)
    if kind == "latent":
        return _Form("latent", (), None)
    mu_code, sigma_code, layer_bits = cursor.u8(f"{where}'s mu"), cursor.u8(f"{where}'s sigma"), cursor.u8(where)
    mus = {v: k for k, v in _MU_CODES.items()}
    sigmas = {v: k for k, v in _SIGMA_CODES.items()}
    if mu_code not in mus or sigma_code not in sigmas or layer_bits & ~(_LAYER_BASIS | _LAYER_DETAIL):
        raise UnsupportedVersionError(
            path, f"{where} stores mu, sigma or layers in a way unknown to this reader (codes {mu_code}, {sigma_code}, "
            f"{layer_bits}); upgrade brdfcodec")
    if not layer_bits:
        raise _fail(path, f"{where}: a layered form holds neither a basis nor a detail layer")
    # A record without a latent (2.1, spec §4.6) stores neither mu nor sigma, and needs a basis layer.
    if (mus[mu_code] == "none") != (sigmas[sigma_code] == "none"):
        raise _fail(path, f"{where} stores {'no mu but a sigma' if mus[mu_code] == 'none' else 'no sigma but a mu'}: "
                    "only a record without a latent (mu and sigma 'none') stores neither")
    if mus[mu_code] == "none" and not layer_bits & _LAYER_BASIS:
        raise _fail(path, f"{where} stores no latent and no basis layer: a record without a latent needs one")
    layers: dict[str, Any] = {}
    if mus[mu_code] is not None:
        layers["mu"] = mus[mu_code]
    if sigmas[sigma_code] is not None:
        layers["sigma"] = sigmas[sigma_code]
    if layer_bits & _LAYER_BASIS:
        first, project = cursor.varint(f"{where}'s basis first"), cursor.varint(f"{where}'s basis projection")
        if basis_sha is None:
            raise _fail(path, f"{where} has a basis layer, but the header names no shared basis")
        if project and mus[mu_code] == "none":
            raise _fail(path, f"{where} stores no latent but projects its base on {project} basis vectors (a record "
                        "without a latent has no base decode to project: project must be 0)")
        # as brdfcodec.format.layered_record.layers_entry writes it: ``first`` and ``project`` only when not 0
        layers["basis"] = {"sha256": basis_sha, "count": 1, **({"first": first} if first else {}),
                           **({"project": project} if project else {})}
    if layer_bits & _LAYER_DETAIL:
        dtypes = {v: k for k, v in _DETAIL_CODES.items()}
        code = cursor.u8(f"{where}'s detail form")
        if code not in dtypes:
            raise UnsupportedVersionError(path, f"{where} has detail form {code}, unknown to this reader; upgrade "
                                          "brdfcodec")
        layers["detail"] = {"transform": "dct3-ycc", "step": 1.0, "dtype": dtypes[code], "length": 1}
    return _Form("layered", (), layers)


def _parse_header(path: str, stored: bytes, preamble_fields: tuple[int, ...], file_size: int) -> BvaeHeader:
    """The binary header (§3): file-level fields, the form table, the record index, the payload CRC, metadata."""
    major, minor, flags, header_length, _ = preamble_fields
    cursor = _Cursor(path, stored)
    sha = cursor.take(32, "the decoder's SHA-256").hex()
    latent_dim = int.from_bytes(cursor.take(2, "latent_dim"), "little")
    if not 1 <= latent_dim <= MAX_LATENT_DIM:
        raise _fail(path, f"latent_dim {latent_dim} is outside [1, {MAX_LATENT_DIM}]")
    dtype_code = cursor.u8("latent_dtype")
    dtypes = {v: k for k, v in _DTYPE_CODES.items()}
    if dtype_code not in dtypes:
        raise UnsupportedVersionError(path, f"latent dtype code {dtype_code} is not supported (0: float32, 1: float16)")
    latent_dtype = dtypes[dtype_code]
    basis_sha = cursor.take(32, "the shared basis' SHA-256").hex() if flags & FLAG_BASIS else None
    form_count = cursor.u8("the form count")
    if not form_count:
        raise _fail(path, "the form table is empty")
    forms = [_parse_form(path, cursor, i, latent_dim, basis_sha) for i in range(form_count)]
    if len({repr(f) for f in forms}) != len(forms):
        raise _fail(path, "the form table states a form twice")
    if basis_sha is not None and not any(f.layers and "basis" in f.layers for f in forms):
        raise _fail(path, "the header names a shared basis, but no record form has a basis layer")
    count = cursor.varint("the record count")
    if not 1 <= count <= MAX_RECORDS:
        raise _fail(path, f"record count {count} is outside [1, {MAX_RECORDS}]")
    itemsize = _DTYPES[latent_dtype].itemsize
    entries: list[RecordEntry] = []
    seen: dict[str, str] = {}
    used: set[int] = set()
    offset = 0
    for i in range(count):
        where = f"record {i}"
        start = cursor.at
        raw_name = cursor.take(cursor.varint(f"{where}'s name length"), f"{where}'s name")
        try:
            entry_name = check_material_name(raw_name.decode("utf-8"))
        except UnicodeDecodeError as error:  # a lone surrogate's bytes (CESU-8) included
            raise _fail(path, f"{where}: its name is not UTF-8 text ({error.reason} at byte {error.start})") from None
        except ValueError as error:
            raise _fail(path, f"{where}: {error}") from None
        key = name_collision_key(entry_name)
        if key in seen:
            twin = "" if seen[key] == entry_name else f" (as {seen[key]!r}: names differ only in case)"
            raise _fail(path, f"material name {entry_name!r} appears twice{twin}")
        seen[key] = entry_name
        label = f"{where} ({entry_name})"
        index = cursor.u8(f"{label}'s form")
        if index >= form_count:
            raise _fail(path, f"{label} uses form {index}, but the table has {form_count}")
        used.add(index)
        form = forms[index]
        layers = None
        if form.kind == "layered":  # --- layered records (issue 14): validated by brdfcodec.format.layered_record

            assert form.layers is not None
            layers = {key: dict(value) if isinstance(value, dict) else value for key, value in form.layers.items()}
            if "basis" in layers:
                layers["basis"]["count"] = cursor.varint(f"{label}'s basis count")
            if "detail" in layers:
                layers["detail"]["step"] = struct.unpack("<d", cursor.take(8, f"{label}'s detail step"))[0]
                layers["detail"]["length"] = cursor.varint(f"{label}'s detail length")
            try:
                length = latent_values_stored(layers, latent_dim) * itemsize + layers_length(layers, label, latent_dim)
            except UnsupportedLayerError as error:
                raise UnsupportedVersionError(path, str(error)) from None
            except ValueError as error:
                raise _fail(path, str(error)) from None
        else:
            length = (2 * latent_dim + len(form.graft_dims)) * itemsize
        overhead = cursor.at - start - len(raw_name)
        entries.append(RecordEntry(entry_name, form.kind, offset, length, {}, form.graft_dims, layers, overhead))
        offset += length
    if len(used) != form_count:
        unused = sorted(set(range(form_count)) - used)
        raise _fail(path, f"record form {unused[0]} is used by no record (a file lists only the forms it uses)")
    payload_crc = int.from_bytes(cursor.take(4, "the payload CRC-32"), "little")
    created_by, decoder_name = "", ""
    rest = stored[cursor.at :]
    if not rest and flags & FLAG_METADATA_ZSTD:
        raise _fail(path, "flag bit 0 (compressed metadata) is set, but the header holds no metadata block")
    if rest:
        raw = _decompress_header(path, rest) if flags & FLAG_METADATA_ZSTD else rest
        created_by, decoder_name, metas = _parse_metadata(path, raw, seen)
        entries = [replace(e, meta=metas.get(e.name, {})) for e in entries]
    records_offset = PREAMBLE_SIZE + header_length
    expected_size = records_offset + offset
    if file_size < expected_size:
        raise _fail(path, f"truncated: the records need {expected_size} bytes, the file has {file_size}")
    if file_size > expected_size:
        raise _fail(path, f"{file_size - expected_size} trailing bytes after the last record")
    return BvaeHeader(
        major=major,
        minor=minor,
        flags=flags,
        decoder=DecoderReference(sha, decoder_name),
        latent_dim=latent_dim,
        latent_dtype=latent_dtype,  # type: ignore[arg-type]
        entries=tuple(entries),
        created_by=created_by,
        header_bytes=header_length,
        records_offset=records_offset,
        file_size=file_size,
        basis_sha256=basis_sha,
        payload_crc32=payload_crc,
        form_count=form_count,
    )


def _parse_metadata(
    path: str, raw: bytes, names: Mapping[str, str]
) -> tuple[str, str, dict[str, Mapping[str, Any]]]:
    """The metadata block (§5): ``created_by``, ``decoder_name`` and each named record's ``meta``."""
    block = _check_json_text(raw, lambda problem: _fail(path, f"metadata: {problem}"))
    if not isinstance(block, dict):
        raise _fail(path, "the metadata block is not a JSON object")
    for key in ("created_by", "decoder_name"):
        if not isinstance(block.get(key, ""), str):
            raise _fail(path, f"metadata field {key!r} must be a string, got {type(block[key]).__name__}")
    records = block.get("records", {})
    if not isinstance(records, dict):
        raise _fail(path, "metadata field 'records' is not a JSON object")
    metas: dict[str, Mapping[str, Any]] = {}
    for name, meta in records.items():
        if names.get(name_collision_key(name)) != name:
            raise _fail(path, f"metadata names the material {name!r}, which the file does not hold")
        if not isinstance(meta, dict):
            raise _fail(path, f"metadata of {name!r} is not a JSON object")
        problem = meta_problem(meta)
        if problem is not None:
            raise _fail(path, f"metadata of {name!r}: {problem}")
        metas[name] = meta
    return block.get("created_by", ""), block.get("decoder_name", ""), metas


def _read_exact(handle: BinaryIO, count: int) -> bytes:
    data = handle.read(count)
    return data if data is not None else b""


def _header_from_handle(path: str, handle: BinaryIO, file_size: int) -> BvaeHeader:
    preamble = _read_exact(handle, PREAMBLE_SIZE)
    fields = _parse_preamble(path, preamble, file_size)
    stored = _read_exact(handle, fields[3])
    if len(stored) != fields[3]:
        raise _fail(path, "truncated header")
    _check_header_crc(path, preamble, stored, fields[2], fields[4])
    return _parse_header(path, stored, fields, file_size)


def _check_payload_crc(path: str, header: BvaeHeader, crc: int) -> None:
    if crc != header.payload_crc32:
        raise BvaeChecksumError(
            path, "payload CRC-32 mismatch: a record is corrupt (re-create or re-download the file)"
        )


def _decode_record(path: str, header: BvaeHeader, entry: RecordEntry, payload: bytes) -> Record:
    """A record from its payload (the payload CRC-32 already checked)."""
    if len(payload) != entry.length:
        raise _fail(path, f"truncated record {entry.name!r}")
    d = header.latent_dim
    itemsize = _DTYPES[header.latent_dtype].itemsize
    n_latent = (2 * d + len(entry.graft_dims)) * itemsize
    if entry.kind == "layered":

        assert entry.layers is not None
        n_latent = latent_values_stored(entry.layers, d) * itemsize
    values = np.frombuffer(payload[:n_latent], dtype=_DTYPES[header.latent_dtype]).astype(np.float32)
    try:
        if entry.kind == "layered":  # --- layered records (issue 14)

            assert entry.layers is not None
            tail = payload[n_latent:]
            return layered_from_payload(entry.name, values, d, entry.layers, tail, entry.meta)
        if entry.kind == "graft":
            return GraftRecord(entry.name, values[:d], values[d : 2 * d], entry.graft_dims, values[2 * d :], entry.meta)
        return LatentRecord(entry.name, values[:d], values[d:], entry.meta)
    except ValueError as error:
        raise _fail(path, f"record {entry.name!r}: {error}") from None


def parse_bvae(data: bytes, path: str | os.PathLike[str] = "<bytes>") -> ParsedBvae:
    """Parse and verify the complete bytes of a ``.bvae`` file.

    Raises
    ------
    BvaeFormatError
        Malformed, truncated, or with trailing bytes.
    BvaeChecksumError
        A CRC-32 does not match.
    UnsupportedVersionError
        Needs a newer reader.
    """
    name = os.fspath(path)
    handle = io.BytesIO(data)
    header = _header_from_handle(name, handle, len(data))
    start = header.records_offset
    _check_payload_crc(name, header, zlib.crc32(memoryview(data)[start:]))
    records = tuple(
        _decode_record(name, header, e, data[start + e.offset : start + e.offset + e.length]) for e in header.entries
    )
    return ParsedBvae(header, records)


def _open_checked(path: str | os.PathLike[str]) -> tuple[BinaryIO, int]:
    target = Path(path)
    if target.is_dir():
        raise IsADirectoryError(21, "is a directory, not a .bvae file", str(target))
    handle = open(target, "rb")  # noqa: SIM115 - closed by the callers
    return handle, os.fstat(handle.fileno()).st_size


def read_header(path: str | os.PathLike[str]) -> BvaeHeader:
    """Read and verify a file's preamble and header only (no record is read, so the payload CRC is not checked)."""
    handle, size = _open_checked(path)
    with handle:
        return _header_from_handle(os.fspath(path), handle, size)


def read_bvae(path: str | os.PathLike[str]) -> ParsedBvae:
    """Read and verify a whole ``.bvae`` file (the header's and the payloads' CRC-32 are checked)."""
    handle, _ = _open_checked(path)
    with handle:
        data = handle.read()
    return parse_bvae(data, path)


class BvaeReader:
    """Random access to the records of a ``.bvae`` file.

    Opening reads the preamble and header, and reads the payloads once to
    check their CRC-32 (one for all records, §3); :meth:`read` then reads
    one record's bytes. Use as a context manager, or call :meth:`close`.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._handle, size = _open_checked(path)
        try:
            self.header = _header_from_handle(os.fspath(path), self._handle, size)
            crc = 0
            while chunk := self._handle.read(1 << 20):
                crc = zlib.crc32(chunk, crc)
            _check_payload_crc(os.fspath(path), self.header, crc)
        except BaseException:
            self._handle.close()
            raise

    def __enter__(self) -> BvaeReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the file."""
        self._handle.close()

    @property
    def names(self) -> list[str]:
        """Material names in file order."""
        return self.header.names

    def read(self, name: str) -> Record:
        """Read one material's record (``KeyError`` if absent); the payloads were verified on opening."""
        entry = self.header.entry(name)
        self._handle.seek(self.header.records_offset + entry.offset)
        return _decode_record(os.fspath(self.path), self.header, entry, _read_exact(self._handle, entry.length))

    def read_all(self) -> list[Record]:
        """Every record, in file order."""
        return [self.read(name) for name in self.names]
