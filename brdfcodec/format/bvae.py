"""The ``.bvae`` file format: read, write and inspect (``spec/bvae-format.md``).

A ``.bvae`` file holds the latent codes of one material or of a library of
materials, and the SHA-256 of the decoder that turns them back into BRDF
tables. This module does not import torch: inspecting a file (``bvae info``)
is instant, and a file can be checked on a machine without a model.

Layout (format 2, little-endian)::

    preamble  24 bytes   magic, version, flags, header length, header CRC-32
    header    N bytes    binary: decoder SHA-256 (since 2.6 by default its first 8
                         bytes), latent size and dtype, the shared basis' SHA-256
                         (once, as short), the form table (how records store
                         μ, σ and their layers, once per form), the record index
                         (name, form, per-record numbers), the payloads' CRC-32;
                         then an optional JSON metadata block (provenance, edits)
    records   ...        raw payloads, contiguous, in index order; the file
                         ends exactly where the last record ends

Every byte is covered by a CRC-32: the preamble and header by the header CRC,
the payloads by the payload CRC in the header. A record's descriptor holds
only its name and what varies between records (:func:`record_overhead`), so a
file costs little more than its payloads and names.

The parts: :mod:`~brdfcodec.format.container` (constants, parsed structures),
:mod:`~brdfcodec.format.strict_json`, :mod:`~brdfcodec.format.writer`, :mod:`~brdfcodec.format.reader`.
This module gathers their names, the one to import.
"""

# ruff: noqa: F401 - the names of the parts, gathered
from brdfcodec.format.container import (
    _CRC_COVERED_PREAMBLE,
    _DTYPE_CODES,
    _DTYPES,
    _LAYER_BASIS,
    _LAYER_DETAIL,
    _PREAMBLE,
    _RECORD_KINDS,
    _SHA256,
    _VARINT_MAX_BYTES,
    _ZSTD_FAST_ABOVE,
    _ZSTD_FAST_LEVEL,
    _ZSTD_LEVEL,
    FLAG_BASIS,
    FLAG_METADATA_ZSTD,
    FLAG_SHORT_REFERENCES,
    FORMAT_MAJOR,
    FORMAT_MINOR,
    KNOWN_FLAGS,
    MAGIC,
    MAX_HEADER_BYTES,
    MAX_HEADER_CONTAINERS,
    MAX_HEADER_DEPTH,
    MAX_HEADER_JSON_BYTES,
    MAX_JSON_INTEGER,
    MAX_RECORDS,
    PREAMBLE_SIZE,
    PROVENANCE_KEYS,
    BvaeHeader,
    BvaeLibrary,
    DecoderReference,
    LatentDtype,
    ParsedBvae,
    Record,
    RecordEntry,
    _Form,
    without_provenance,
)
from brdfcodec.format.material_names import MAX_NAME_LENGTH
from brdfcodec.format.reader import (
    BvaeReader,
    _check_header_crc,
    _check_payload_crc,
    _Cursor,
    _decode_record,
    _decompress_header,
    _fail,
    _header_from_handle,
    _open_checked,
    _parse_form,
    _parse_header,
    _parse_metadata,
    _parse_preamble,
    _read_exact,
    parse_bvae,
    read_bvae,
    read_header,
)
from brdfcodec.format.records import MAX_LATENT_DIM, GraftRecord, LatentRecord
from brdfcodec.format.strict_json import (
    _LONG_INTEGER,
    _check_json_structure,
    _check_json_text,
    _exact_int,
    _finite_float,
    _reject_constant,
    _unique_keys,
    canonical_json,
)
from brdfcodec.format.writer import (
    _DETAIL_CODES,
    _KIND_CODES,
    _MU_CODES,
    _SIGMA_CODES,
    MAX_FORMS,
    _form_bytes,
    _form_of,
    _payload,
    _varint,
    _varint_size,
    descriptor_size,
    encode_bvae,
    record_overhead,
    record_size,
    write_bvae,
)

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
