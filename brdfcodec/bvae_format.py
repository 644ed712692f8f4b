"""The ``.bvae`` file format: read, write and inspect (``spec/bvae-format.md``).

A ``.bvae`` file holds the latent codes of one material or of a library of
materials, and the SHA-256 of the decoder that turns them back into BRDF
tables. This module does not import torch: inspecting a file (``bvae info``)
is instant, and a file can be checked on a machine without a model.

Layout (little-endian)::

    preamble  24 bytes   magic, version, flags, header length, header CRC-32
    header    N bytes    UTF-8 JSON (zstandard-compressed when flag bit 0 is set):
                         decoder reference, latent dtype, the record index
    records   ...        raw payloads, contiguous, in index order; the file
                         ends exactly where the last record ends

Every byte is covered by a CRC-32: the preamble and header by the header CRC,
each record by the CRC in its index entry. A reader can therefore decode one
material of a library by reading the preamble, the header and that record.
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.atomic import atomic_output
from brdfcodec.errors import BvaeChecksumError, BvaeFormatError, UnsupportedVersionError
from brdfcodec.material_names import MAX_NAME_LENGTH as MAX_NAME_LENGTH  # re-exported
from brdfcodec.material_names import check_material_name, name_collision_key
from brdfcodec.version import __version__

__all__ = [
    "FORMAT_MAJOR",
    "FORMAT_MINOR",
    "MAGIC",
    "MAX_HEADER_BYTES",
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
    "read_bvae",
    "read_header",
    "write_bvae",
]

#: First 8 bytes of every ``.bvae`` file (a non-ASCII byte, the name, CR LF, EOF: catches text-mode transfers).
MAGIC = b"\x89BVAE\r\n\x1a"
#: Major version written and read; a file of another major version is refused.
FORMAT_MAJOR = 1
#: Minor version written; readers accept any minor version of their major version.
#: 1.1 added the "layered" record kind (issue 14); a 1.0 reader refuses it by its kind.
#: 1.2 added the basis layer and compact sigma of layered records; a 1.1 reader refuses them as unknown layers.
#: 1.3 added the basis layer's ``first`` vector; a 1.2 reader refuses it as an unknown basis field.
#: 1.4 added compact μ and shared σ of layered records; a 1.3 reader refuses them as an unknown layer / sigma mode.
FORMAT_MINOR = 6
#: Largest stored header, in bytes (compressed size when compressed).
MAX_HEADER_BYTES = 1 << 20
#: Largest decompressed header, in bytes.
MAX_HEADER_JSON_BYTES = 16 << 20
#: Largest number of records in one file.
MAX_RECORDS = 65536
#: Largest latent dimension a file may declare.
MAX_LATENT_DIM = 1024
#: Most JSON objects and arrays (nested ones included) a header may hold: bounds the work of parsing.
MAX_HEADER_CONTAINERS = 1 << 19
#: Deepest nesting of JSON objects and arrays in a header.
MAX_HEADER_DEPTH = 64
#: Largest magnitude of a JSON integer in a header (I-JSON, RFC 7493: exact in binary64).
MAX_JSON_INTEGER = (1 << 53) - 1

FLAG_HEADER_ZSTD = 1 << 0
KNOWN_FLAGS = FLAG_HEADER_ZSTD

_PREAMBLE = struct.Struct("<8sHHIII")
PREAMBLE_SIZE = _PREAMBLE.size  # 24
_CRC_COVERED_PREAMBLE = PREAMBLE_SIZE - 4
_ZSTD_LEVEL = 19
#: Headers longer than this (in JSON bytes) are compressed at a faster level (§3.1): level 19 runs at ~0.3 MB/s.
_ZSTD_FAST_ABOVE = 1 << 20
_ZSTD_FAST_LEVEL = 3

LatentDtype = Literal["float32", "float16"]
_DTYPES: dict[str, np.dtype] = {"float32": np.dtype("<f4"), "float16": np.dtype("<f2")}
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_RECORD_KINDS = ("latent", "graft", "layered")  # "layered": brdfcodec.layers.record


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


def _as_latent(values: npt.ArrayLike, label: str) -> np.ndarray:
    array = np.array(values, dtype=np.float32).reshape(-1)
    array.setflags(write=False)
    if not np.isfinite(array).all():
        raise ValueError(f"{label} must be finite, got {array}")
    return array


def _check_name(name: object) -> str:
    return check_material_name(name)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _meta_problem(meta: Mapping[str, Any]) -> str | None:
    """Why a record's ``meta`` breaks the types of §5, or None (other keys are free JSON)."""
    for key in ("source_sha256", "encoder_sha256"):
        if key in meta and not (isinstance(meta[key], str) and _SHA256.match(meta[key])):
            return f"meta field {key!r} must be 64 lower-case hex digits, got {meta[key]!r}"
    if "relae" in meta:
        relae = meta["relae"]
        if not isinstance(relae, Mapping):
            return f"meta field 'relae' must be an object, got {type(relae).__name__}"
        for part in ("mapped", "linear"):
            if part in relae and not (_is_number(relae[part]) and math.isfinite(relae[part]) and relae[part] >= 0):
                return f"meta field 'relae.{part}' must be a finite number >= 0, got {relae[part]!r}"
    if "edit" in meta:
        edit = meta["edit"]
        if not isinstance(edit, Mapping) or not isinstance(edit.get("op"), str):
            return "meta field 'edit' must be an object with a string 'op'"
    if "source_kind" in meta and not isinstance(meta["source_kind"], str):
        return f"meta field 'source_kind' must be a string, got {meta['source_kind']!r}"
    if "effort" in meta:
        effort = meta["effort"]
        if not (isinstance(effort, int) and not isinstance(effort, bool) and 0 <= effort <= 3):
            return f"meta field 'effort' must be an integer in [0, 3], got {effort!r}"
    if "rate" in meta and not isinstance(meta["rate"], Mapping):
        return f"meta field 'rate' must be an object, got {type(meta['rate']).__name__}"
    return None


@dataclass(frozen=True)
class LatentRecord:
    """One material as the encoder's posterior ``N(mu, diag(sigma²))``.

    Attributes
    ----------
    name : str
        Material name, unique in its file.
    mu, sigma : ndarray of float32, shape (latent_dim,)
        Posterior mean (the code that is decoded) and standard deviation (> 0),
        in latent units (the prior is N(0, 1)).
    meta : dict
        Optional facts (``spec/bvae-format.md`` §5): ``source_sha256``,
        ``relae`` (``{"mapped": float, "linear": float}``), ``encoder_sha256``,
        ``source_kind`` (str), ``effort`` (int, 0–3), ``rate`` (object),
        ``edit`` (how an edited material was made), and any other JSON value.
    """

    name: str
    mu: np.ndarray
    sigma: np.ndarray
    meta: Mapping[str, Any] = field(default_factory=dict)

    kind: Literal["latent"] = field(default="latent", init=False)

    def __post_init__(self) -> None:
        _check_name(self.name)
        object.__setattr__(self, "mu", _as_latent(self.mu, "mu"))
        object.__setattr__(self, "sigma", _as_latent(self.sigma, "sigma"))
        if self.mu.shape != self.sigma.shape:
            raise ValueError(f"mu and sigma differ in length: {self.mu.shape} and {self.sigma.shape}")
        if not 1 <= self.mu.size <= MAX_LATENT_DIM:
            raise ValueError(f"latent dimension must be 1 to {MAX_LATENT_DIM}, got {self.mu.size}")
        if not (self.sigma > 0).all():
            raise ValueError(f"sigma must be > 0, got {self.sigma}")
        if not isinstance(self.meta, Mapping):
            raise ValueError(f"meta must be a mapping, got {type(self.meta).__name__}")
        problem = _meta_problem(self.meta)
        if problem is not None:
            raise ValueError(f"{self.name}: {problem}")
        object.__setattr__(self, "meta", dict(self.meta))

    @property
    def latent_dim(self) -> int:
        """Length of the latent code."""
        return int(self.mu.size)

    def payload_values(self) -> np.ndarray:
        """Values in payload order: ``mu`` then ``sigma``."""
        return np.concatenate([self.mu, self.sigma])


@dataclass(frozen=True)
class GraftRecord:
    """A composite material made by green-channel grafting (paper §5; spec §4.2).

    The material decodes ``mu`` (M1) and a second code equal to ``mu`` except
    at ``graft_dims``, where it takes ``graft_values`` (M2); its table is M1
    with M1's green channel replaced by M2's red channel.

    Attributes
    ----------
    name, mu, sigma, meta
        As in :class:`LatentRecord` (``mu``/``sigma`` are V1's).
    graft_dims : tuple of int
        Latent dimensions that control colour (the model's colour dimensions).
    graft_values : ndarray of float32, shape (len(graft_dims),)
        V2's values at those dimensions: the extra parameters.
    """

    name: str
    mu: np.ndarray
    sigma: np.ndarray
    graft_dims: tuple[int, ...]
    graft_values: np.ndarray
    meta: Mapping[str, Any] = field(default_factory=dict)

    kind: Literal["graft"] = field(default="graft", init=False)

    def __post_init__(self) -> None:
        LatentRecord.__post_init__(self)  # type: ignore[arg-type]  # same checks on the shared fields
        dims = tuple(int(d) for d in self.graft_dims)
        if not dims or len(set(dims)) != len(dims) or not all(0 <= d < self.mu.size for d in dims):
            raise ValueError(f"graft_dims must be distinct latent indices in [0, {self.mu.size}), got {dims}")
        object.__setattr__(self, "graft_dims", dims)
        object.__setattr__(self, "graft_values", _as_latent(self.graft_values, "graft_values"))
        if self.graft_values.size != len(dims):
            raise ValueError(f"need one graft value per graft dimension, got {self.graft_values.size} for {dims}")

    @property
    def latent_dim(self) -> int:
        """Length of the latent code."""
        return int(self.mu.size)

    def second_code(self) -> np.ndarray:
        """V2: ``mu`` with ``graft_values`` at ``graft_dims``."""
        v2 = self.mu.copy()
        v2[list(self.graft_dims)] = self.graft_values
        return v2

    def payload_values(self) -> np.ndarray:
        """Values in payload order: ``mu``, ``sigma``, ``graft_values``."""
        return np.concatenate([self.mu, self.sigma, self.graft_values])


Record = LatentRecord | GraftRecord


@dataclass(frozen=True)
class RecordEntry:
    """One record as the header's index describes it (no payload read)."""

    name: str
    kind: str
    offset: int
    length: int
    crc32: int
    meta: Mapping[str, Any]
    graft_dims: tuple[int, ...] = ()
    layers: Mapping[str, Any] | None = None  # kind "layered" only (brdfcodec.layers.record)


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
        Stored size of the header (after compression, if any).
    records_offset : int
        File offset of the first record.
    file_size : int
        Total size of the file, in bytes.
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


def _payload_length(kind: str, latent_dim: int, n_graft: int, itemsize: int) -> int:
    n_values = 2 * latent_dim + (n_graft if kind == "graft" else 0)
    return n_values * itemsize


def encode_bvae(
    records: Sequence[Record],
    decoder: DecoderReference,
    *,
    latent_dtype: LatentDtype = "float32",
    compress_header: bool | None = None,
) -> bytes:
    """Serialise records to the bytes of a ``.bvae`` file.

    Parameters
    ----------
    records : sequence of LatentRecord or GraftRecord
        At least one; names unique; all of the same latent dimension.
    decoder : DecoderReference
        The decoder the latents belong to.
    latent_dtype : {"float32", "float16"}, default "float32"
        Storage of the latent values. float16 halves the payload; values are
        rounded to nearest (|values| above 65504 are refused).
    compress_header : bool, optional
        Compress the JSON header with zstandard. By default it is compressed
        when that makes it smaller.

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
    dtype = _DTYPES[latent_dtype]
    payloads: list[bytes] = []
    index: list[dict[str, Any]] = []
    offset = 0
    for record in records:
        values = record.payload_values()
        if latent_dtype == "float16" and np.abs(values).max(initial=0.0) > np.finfo(np.float16).max:
            raise ValueError(f"{record.name}: latent values exceed the float16 range; store them as float32")
        payload = values.astype(dtype).tobytes()
        # --- layered records (issue 14, brdfcodec.layers): layer bytes follow mu and sigma
        if record.kind == "layered":
            from brdfcodec.layers.record import layers_entry

            payload += record.layer_bytes()  # type: ignore[union-attr]
        # ---
        entry: dict[str, Any] = {
            "name": record.name,
            "kind": record.kind,
            "offset": offset,
            "length": len(payload),
            "crc32": zlib.crc32(payload),
        }
        if isinstance(record, GraftRecord):
            entry["graft_dims"] = list(record.graft_dims)
        if record.kind == "layered":
            entry["layers"] = layers_entry(record)  # type: ignore[arg-type]
        if record.meta:
            entry["meta"] = dict(record.meta)
        payloads.append(payload)
        index.append(entry)
        offset += len(payload)
    header = {
        "format": "bvae",
        "created_by": f"brdfcodec {__version__}",
        "decoder": {"sha256": decoder.sha256, "name": decoder.name},
        "latent_dim": latent_dim,
        "latent_dtype": latent_dtype,
        "records": index,
    }
    stored = canonical_json(header)
    if len(stored) > MAX_HEADER_JSON_BYTES:
        raise ValueError(f"header of {len(stored)} bytes exceeds {MAX_HEADER_JSON_BYTES}; split the library")
    flags = 0
    if compress_header is not False:
        import zstandard

        level = _ZSTD_LEVEL if len(stored) <= _ZSTD_FAST_ABOVE else _ZSTD_FAST_LEVEL
        packed = zstandard.ZstdCompressor(level=level, write_content_size=True).compress(stored)
        if compress_header or len(packed) < len(stored):
            stored, flags = packed, FLAG_HEADER_ZSTD
    if len(stored) > MAX_HEADER_BYTES:
        raise ValueError(f"stored header of {len(stored)} bytes exceeds {MAX_HEADER_BYTES}; split the library")
    head = _PREAMBLE.pack(MAGIC, FORMAT_MAJOR, FORMAT_MINOR, flags, len(stored), 0)[:_CRC_COVERED_PREAMBLE]
    crc = zlib.crc32(stored, zlib.crc32(head))
    return head + struct.pack("<I", crc) + stored + b"".join(payloads)


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
            "upgrade brdfcodec, or re-create the file with this version"
        )
    if header_length > MAX_HEADER_BYTES:
        raise _fail(path, f"header length {header_length} exceeds the maximum of {MAX_HEADER_BYTES} bytes")
    if PREAMBLE_SIZE + header_length > file_size:
        needed = PREAMBLE_SIZE + header_length
        raise _fail(path, f"truncated: the header needs {needed} bytes, the file has {file_size}")
    return major, minor, flags, header_length, crc


def _decompress_header(path: str, stored: bytes) -> bytes:
    """The one zstandard frame of a compressed header (§3): declared size within the limit, nothing after it."""
    import zstandard

    try:
        params = zstandard.get_frame_parameters(stored)
        if params.content_size <= 0 or params.content_size > MAX_HEADER_JSON_BYTES:
            raise _fail(path, "compressed header does not declare a content size within the limit")
        raw = zstandard.ZstdDecompressor().decompress(stored, max_output_size=MAX_HEADER_JSON_BYTES)
        stream = zstandard.ZstdDecompressor().decompressobj()
        stream.decompress(stored)  # bounded: the frame just decompressed within the limit
    except zstandard.ZstdError as error:
        raise _fail(path, f"compressed header cannot be decompressed ({error})") from None
    if stream.unused_data:
        raise _fail(path, f"{len(stream.unused_data)} bytes after the compressed header's zstandard frame")
    return raw


def _header_json(path: str, preamble: bytes, stored: bytes, flags: int, crc: int) -> dict[str, Any]:
    if zlib.crc32(stored, zlib.crc32(preamble[:_CRC_COVERED_PREAMBLE])) != crc:
        raise BvaeChecksumError(path, "header CRC-32 mismatch: the file is corrupt (re-create or re-download it)")
    if flags & ~KNOWN_FLAGS:  # after the CRC: a flipped bit is corruption, a set bit under a good CRC a new feature
        raise UnsupportedVersionError(
            path, f"flag bits 0x{flags & ~KNOWN_FLAGS:08x} name features this reader does not know; upgrade brdfcodec"
        )
    raw = _decompress_header(path, stored) if flags & FLAG_HEADER_ZSTD else stored
    header = _check_json_text(raw, lambda problem: _fail(path, problem))
    if not isinstance(header, dict):
        raise _fail(path, "header is not a JSON object")
    return header


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not allowed in a .bvae header")


def _require(path: str, mapping: Mapping[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
    if key not in mapping:
        raise _fail(path, f"{where} lacks the field {key!r}")
    value = mapping[key]
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise _fail(path, f"{where} field {key!r} has the wrong type ({type(value).__name__})")
    return value


def _parse_header(path: str, header: dict[str, Any], preamble_fields: tuple[int, ...], file_size: int) -> BvaeHeader:
    major, minor, flags, header_length, _ = preamble_fields
    if header.get("format") != "bvae":
        raise _fail(path, "header field 'format' is not 'bvae'")
    decoder = _require(path, header, "decoder", dict, "header")
    sha = _require(path, decoder, "sha256", str, "decoder reference")
    name = _require(path, decoder, "name", str, "decoder reference")
    if not _SHA256.match(sha):
        raise _fail(path, f"decoder SHA-256 {sha!r} is not 64 lower-case hex digits")
    latent_dim = _require(path, header, "latent_dim", int, "header")
    if not 1 <= latent_dim <= MAX_LATENT_DIM:
        raise _fail(path, f"latent_dim {latent_dim} is outside [1, {MAX_LATENT_DIM}]")
    latent_dtype = _require(path, header, "latent_dtype", str, "header")
    if latent_dtype not in _DTYPES:
        raise UnsupportedVersionError(path, f"latent dtype {latent_dtype!r} is not supported (float32, float16)")
    raw_entries = _require(path, header, "records", list, "header")
    if not 1 <= len(raw_entries) <= MAX_RECORDS:
        raise _fail(path, f"record count {len(raw_entries)} is outside [1, {MAX_RECORDS}]")
    itemsize = _DTYPES[latent_dtype].itemsize
    created_by = header.get("created_by", "")
    if not isinstance(created_by, str):
        raise _fail(path, f"header field 'created_by' must be a string, got {type(created_by).__name__}")
    entries: list[RecordEntry] = []
    seen: dict[str, str] = {}
    offset = 0
    for i, raw in enumerate(raw_entries):
        where = f"record {i}"
        if not isinstance(raw, dict):
            raise _fail(path, f"{where} is not a JSON object")
        entry_name = _require(path, raw, "name", str, where)
        try:
            _check_name(entry_name)
        except ValueError as error:
            raise _fail(path, f"{where}: {error}") from None
        key = name_collision_key(entry_name)
        if key in seen:
            twin = "" if seen[key] == entry_name else f" (as {seen[key]!r}: names differ only in case)"
            raise _fail(path, f"material name {entry_name!r} appears twice{twin}")
        seen[key] = entry_name
        kind = _require(path, raw, "kind", str, where)
        if kind not in _RECORD_KINDS:
            raise UnsupportedVersionError(
                path, f"{where} ({entry_name}) has record kind {kind!r}, unknown to this reader; upgrade brdfcodec"
            )
        graft_dims: tuple[int, ...] = ()
        if kind == "graft":
            dims = _require(path, raw, "graft_dims", list, where)
            if (
                not dims
                or len(dims) > latent_dim
                or not all(isinstance(d, int) and not isinstance(d, bool) and 0 <= d < latent_dim for d in dims)
                or len(set(dims)) != len(dims)
            ):
                raise _fail(path, f"{where} ({entry_name}) has invalid graft_dims {dims!r}")
            graft_dims = tuple(dims)
        elif "graft_dims" in raw:
            raise _fail(path, f"{where} ({entry_name}) of kind {kind!r} has graft_dims (only graft records do)")
        if kind != "layered" and "layers" in raw:
            raise _fail(path, f"{where} ({entry_name}) of kind {kind!r} has layers (only layered records do)")
        start = _require(path, raw, "offset", int, where)
        length = _require(path, raw, "length", int, where)
        crc = _require(path, raw, "crc32", int, where)
        meta = raw.get("meta", {})
        if not isinstance(meta, dict):
            raise _fail(path, f"{where} ({entry_name}) field 'meta' is not a JSON object")
        problem = _meta_problem(meta)
        if problem is not None:
            raise _fail(path, f"{where} ({entry_name}): {problem}")
        if start != offset:
            raise _fail(path, f"{where} ({entry_name}) starts at {start}, expected {offset} (records are contiguous)")
        expected = _payload_length(kind, latent_dim, len(graft_dims), itemsize)
        layers = None
        if kind == "layered":  # --- layered records (issue 14): validated by brdfcodec.layers.record
            from brdfcodec.layers.record import UnsupportedLayerError, latent_values_stored, layers_length

            layers = raw.get("layers")
            try:
                tail = layers_length(layers, f"{where} ({entry_name})", latent_dim)
                expected = latent_values_stored(layers, latent_dim) * itemsize + tail  # type: ignore[arg-type]
            except UnsupportedLayerError as error:
                raise UnsupportedVersionError(path, str(error)) from None
            except ValueError as error:
                raise _fail(path, str(error)) from None
        if length != expected:
            raise _fail(path, f"{where} ({entry_name}) has length {length}, expected {expected} for kind {kind!r}")
        if not 0 <= crc <= 0xFFFFFFFF:
            raise _fail(path, f"{where} ({entry_name}) has an invalid crc32")
        entries.append(RecordEntry(entry_name, kind, start, length, crc, meta, graft_dims, layers))
        offset += length
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
        decoder=DecoderReference(sha, name),
        latent_dim=latent_dim,
        latent_dtype=latent_dtype,  # type: ignore[arg-type]
        entries=tuple(entries),
        created_by=created_by,
        header_bytes=header_length,
        records_offset=records_offset,
        file_size=file_size,
    )


def _read_exact(handle: BinaryIO, count: int) -> bytes:
    data = handle.read(count)
    return data if data is not None else b""


def _header_from_handle(path: str, handle: BinaryIO, file_size: int) -> BvaeHeader:
    preamble = _read_exact(handle, PREAMBLE_SIZE)
    fields = _parse_preamble(path, preamble, file_size)
    stored = _read_exact(handle, fields[3])
    if len(stored) != fields[3]:
        raise _fail(path, "truncated header")
    header = _header_json(path, preamble, stored, fields[2], fields[4])
    return _parse_header(path, header, fields, file_size)


def _decode_record(path: str, header: BvaeHeader, entry: RecordEntry, payload: bytes) -> Record:
    if len(payload) != entry.length:
        raise _fail(path, f"truncated record {entry.name!r}")
    if zlib.crc32(payload) != entry.crc32:
        raise BvaeChecksumError(
            path, f"record {entry.name!r}: CRC-32 mismatch, the file is corrupt (re-create or re-download it)"
        )
    d = header.latent_dim
    n_latent = _payload_length(entry.kind, d, len(entry.graft_dims), _DTYPES[header.latent_dtype].itemsize)
    if entry.kind == "layered":
        from brdfcodec.layers.record import latent_values_stored

        assert entry.layers is not None
        n_latent = latent_values_stored(entry.layers, d) * _DTYPES[header.latent_dtype].itemsize
    values = np.frombuffer(payload[:n_latent], dtype=_DTYPES[header.latent_dtype]).astype(np.float32)
    try:
        if entry.kind == "layered":  # --- layered records (issue 14)
            from brdfcodec.layers.record import layered_from_payload

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
    """Read and verify a file's preamble and header only (no record is read)."""
    handle, size = _open_checked(path)
    with handle:
        return _header_from_handle(os.fspath(path), handle, size)


def read_bvae(path: str | os.PathLike[str]) -> ParsedBvae:
    """Read and verify a whole ``.bvae`` file (every record's CRC is checked)."""
    handle, _ = _open_checked(path)
    with handle:
        data = handle.read()
    return parse_bvae(data, path)


class BvaeReader:
    """Random access to the records of a ``.bvae`` file.

    Opening reads the preamble and header only; :meth:`read` then reads one
    record's bytes. Use as a context manager, or call :meth:`close`.

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
        """Read and verify one material's record (``KeyError`` if absent)."""
        entry = self.header.entry(name)
        self._handle.seek(self.header.records_offset + entry.offset)
        return _decode_record(os.fspath(self.path), self.header, entry, _read_exact(self._handle, entry.length))

    def read_all(self) -> list[Record]:
        """Every record, in file order."""
        return [self.read(name) for name in self.names]
