"""The ``.bvae`` container's constants and parsed structures (``spec/bvae-format.md`` §2–§4).

Preamble, header, decoder reference, record entries and forms.

Part of :mod:`brdfcodec.format.bvae`, which re-exports its names.
"""

from __future__ import annotations

import functools
import re
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from brdfcodec.format.material_names import MAX_NAME_LENGTH as MAX_NAME_LENGTH  # re-exported
from brdfcodec.format.records import MAX_LATENT_DIM as MAX_LATENT_DIM  # re-exported
from brdfcodec.format.records import GraftRecord, LatentRecord
from brdfcodec.io.hashing import SHORT_REFERENCE_BYTES, is_reference_hex, refers_to

__all__ = [
    "FORMAT_MAJOR",
    "FORMAT_MINOR",
    "MAGIC",
    "MAX_HEADER_BYTES",
    "PROVENANCE_KEYS",
    "BvaeHeader",
    "DecoderReference",
    "ParsedBvae",
    "Record",
    "RecordEntry",
    "without_provenance",
]

#: First 8 bytes of every ``.bvae`` file (a non-ASCII byte, the name, CR LF, EOF: catches text-mode transfers).
MAGIC = b"\x89BVAE\r\n\x1a"
#: Major version written and read; a file of another major version (the development format 1.x too) is refused.
#: 2.0 (issue 40): a binary header and index, file-level facts stated once, metadata opt-in in a JSON block.
FORMAT_MAJOR = 2
#: Minor version written; readers accept any minor version of their major version.
#: 2.1: basis-only layered records (``layers.mu`` and ``layers.sigma`` ``"none"``: no latent, spec §4.6).
#: 2.2: a latent without σ (``layers.sigma`` ``"none"`` beside a stored μ), which may hold no layer (spec §4.4).
#: 2.3: packed basis layers (form layer bit 2 and a top width: spec §4.7).
#: 2.4: entropy-coded basis layers (form layer bit 3, a prior of two bytes, a length per record: spec §4.8).
#: 2.5: μ entropy-coded in the basis layer (form ``mu`` 4 and a grid exponent: spec §4.9).
#: 2.6: short references (flag bit 2: the decoder and the shared basis named by 8 bytes of their SHA-256, §3.1).
#: 2.7: form variants (form kind 3: an earlier layered form's index and the fields that differ, §3.2).
#: A writer states the lowest minor version a file needs (2.1 unless a record leaves σ out, packs or codes its basis).
FORMAT_MINOR = 7
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
#: Flag bit 2 (format 2.6): the header names its decoder and shared basis by short references, the first 8 bytes of
#: their SHA-256 (spec §3.1).
FLAG_SHORT_REFERENCES = 1 << 2
KNOWN_FLAGS = FLAG_METADATA_ZSTD | FLAG_BASIS | FLAG_SHORT_REFERENCES
#: Longest varint (LEB128) in a header, in bytes: values below 2^28.
_VARINT_MAX_BYTES = 4

_PREAMBLE = struct.Struct("<8sHHIII")
PREAMBLE_SIZE = _PREAMBLE.size  # 24
_CRC_COVERED_PREAMBLE = PREAMBLE_SIZE - 4
_ZSTD_LEVEL = 19
#: Headers longer than this (in JSON bytes) are compressed at a faster level (§3.1): level 19 is slow on large inputs.
_ZSTD_FAST_ABOVE = 1 << 20
_ZSTD_FAST_LEVEL = 3

LatentDtype = Literal["float32", "float16"]
_DTYPES: dict[str, np.dtype] = {"float32": np.dtype("<f4"), "float16": np.dtype("<f2")}
#: Layer bits of a form (§3.2); bit 2: the basis layer is packed (2.3, §4.7).
_LAYER_BASIS, _LAYER_DETAIL, _LAYER_PACKED = 1, 2, 4
#: Form layer bit 3 (format 2.4): the basis layer is entropy-coded under the form's prior (spec §4.8).
_LAYER_CODED = 8

_DTYPE_CODES = {"float32": 0, "float16": 1}
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_RECORD_KINDS = ("latent", "graft", "layered")  # "layered": brdfcodec.format.layered_record.LayeredRecord


@dataclass(frozen=True)
class DecoderReference:
    """The decoder a file's latents belong to.

    Attributes
    ----------
    sha256 : str
        Lower-case hex SHA-256 of the decoder weight file (``decoder.safetensors``): 64 hex digits, or the first
        16 of them where a file names its decoder by a short reference (format 2.6, spec §3.1).
    name : str
        Readable model name (informative; the hash decides).
    """

    sha256: str
    name: str

    def __post_init__(self) -> None:
        if not is_reference_hex(self.sha256):
            raise ValueError(f"decoder SHA-256 must be 64 lower-case hex digits (or a short reference's first 16), "
                             f"got {self.sha256!r}")
        if not isinstance(self.name, str):
            raise ValueError(f"decoder name must be a string, got {self.name!r}")

    @property
    def short(self) -> bool:
        """Whether only the first 8 bytes of the hash are known (a file with short references, spec §3.1)."""
        return len(self.sha256) == 2 * SHORT_REFERENCE_BYTES

    def matches(self, sha256: str) -> bool:
        """Whether this reference names the decoder whose weight file has this full SHA-256 (64 hex digits)."""
        return refers_to(self.sha256, sha256)

    def shortened(self) -> DecoderReference:
        """The same decoder named by a short reference (its hash's first 16 hex digits)."""
        return DecoderReference(self.sha256[: 2 * SHORT_REFERENCE_BYTES], self.name)


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
