"""Writing ``.bvae`` files (``spec/bvae-format.md`` §3–§4).

Record descriptors, the form table, the header and the payloads.

Part of :mod:`brdfcodec.format.bvae`, which re-exports its names.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from brdfcodec.format.container import (
    _CRC_COVERED_PREAMBLE,
    _DTYPE_CODES,
    _DTYPES,
    _LAYER_BASIS,
    _LAYER_CODED,
    _LAYER_DETAIL,
    _LAYER_PACKED,
    _PREAMBLE,
    _VARINT_MAX_BYTES,
    _ZSTD_FAST_ABOVE,
    _ZSTD_FAST_LEVEL,
    _ZSTD_LEVEL,
    FLAG_BASIS,
    FLAG_METADATA_ZSTD,
    FLAG_SHORT_REFERENCES,
    FORMAT_MAJOR,
    MAGIC,
    MAX_HEADER_BYTES,
    MAX_HEADER_JSON_BYTES,
    MAX_RECORDS,
    DecoderReference,
    LatentDtype,
    Record,
)
from brdfcodec.format.form_variants import VARIANT_KIND, best_variant
from brdfcodec.format.layered_record import (
    layers_entry,
)
from brdfcodec.format.material_names import MAX_NAME_LENGTH as MAX_NAME_LENGTH  # re-exported
from brdfcodec.format.material_names import name_collision_key
from brdfcodec.format.records import MAX_LATENT_DIM as MAX_LATENT_DIM  # re-exported
from brdfcodec.format.records import GraftRecord
from brdfcodec.format.strict_json import canonical_json
from brdfcodec.io.atomic import atomic_output
from brdfcodec.io.hashing import SHORT_REFERENCE_BYTES
from brdfcodec.version import __version__

__all__ = ["encode_bvae", "descriptor_size", "record_overhead", "record_size", "write_bvae"]

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


def record_overhead(name: str, *, basis_count: int | None = None, detail_bytes: int | None = None,
                    basis_bytes: int | None = None) -> int:
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
    basis_bytes : int, optional
        Bytes of an entropy-coded basis layer (format 2.4), whose descriptor states its length (a varint).

    Returns
    -------
    int
    """
    size = _varint_size(len(name.encode("utf-8"))) + 1
    if basis_count is not None:
        size += _varint_size(basis_count)
    if basis_bytes is not None:
        size += _varint_size(basis_bytes)
    if detail_bytes is not None:
        size += 8 + _varint_size(detail_bytes)
    return size


def descriptor_size(record: Record) -> int:
    """:func:`record_overhead` of a record: its descriptor's bytes beyond its name's."""
    basis, detail = getattr(record, "basis", None), getattr(record, "detail", None)
    coded = basis is not None and getattr(basis, "prior", None) is not None
    return record_overhead(record.name, basis_count=None if basis is None else basis.count,
                           detail_bytes=None if detail is None else detail.nbytes,
                           basis_bytes=basis.nbytes if coded else None)


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
_MU_CODES: dict[str | None, int] = {None: 0, "int8": 1, "int8-fixed": 2, "none": 3, "coded": 4}
_SIGMA_CODES: dict[str | None, int] = {None: 0, "log2-u8": 1, "log2-u8-shared": 2, "none": 3}
_DETAIL_CODES = {"int16": 0, "int32": 1}  # transform "dct3-ycc", the only one
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
            None if basis is None else (int(basis.get("first", 0)), int(basis.get("project", 0)),
                                        int(basis.get("top", 0)),
                                        tuple(basis["prior"]) if "prior" in basis else None,
                                        int(basis.get("mu_step", 0))),
            None if detail is None else str(detail["dtype"]))


def _form_bytes(form: tuple[Any, ...]) -> bytes:
    kind = form[0]
    out = bytes([_KIND_CODES[kind]])
    if kind == "graft":
        return out + _varint(len(form[1])) + b"".join(_varint(d) for d in form[1])
    if kind == "layered":
        _, mu, sigma, basis, detail = form
        layers = (_LAYER_BASIS if basis is not None else 0) | (_LAYER_DETAIL if detail is not None else 0)
        if basis is not None and basis[2]:
            layers |= _LAYER_PACKED
        if basis is not None and basis[3] is not None:
            layers |= _LAYER_CODED
        out += bytes([_MU_CODES[mu], _SIGMA_CODES[sigma], layers])
        if basis is not None:
            out += _varint(basis[0]) + _varint(basis[1])
            if basis[2]:
                out += bytes([basis[2]])
            if basis[3] is not None:  # the coded layer's prior (format 2.4): amplitude, decay
                out += bytes(basis[3])
            if basis[4]:  # a coded μ's grid exponent (format 2.5)
                out += bytes([basis[4]])
        if detail is not None:
            out += bytes([_DETAIL_CODES[detail]])
    return out


def _form_table(forms: Sequence[tuple[Any, ...]], variants: bool) -> list[bytes]:
    """The form table's entries (§3.2): each form in full, or, with ``variants`` (since 2.7), as the variant of
    an earlier form where that is shorter (:func:`~brdfcodec.format.form_variants.best_variant`)."""
    full = [_form_bytes(form) for form in forms]
    if not variants:
        return full
    return [best_variant(entry, full[:i]) for i, entry in enumerate(full)]


def _minor_needed(records: Sequence[Record], short_references: bool, variants: bool = False) -> int:
    """The lowest minor version that holds these records (§2): 7 once a form is a variant, 6 with short
    references, 5 once a record entropy-codes μ, 4 once a basis layer is entropy-coded, 3 once one is packed, 2
    once a record stores a latent without σ, else 1."""
    if variants:
        return 7
    if short_references:
        return 6
    if any(getattr(r, "coded_mu", 0) for r in records):
        return 5
    if any(getattr(getattr(r, "basis", None), "prior", None) is not None for r in records):
        return 4
    if any(getattr(getattr(r, "basis", None), "top", 0) for r in records):
        return 3
    without_sigma = any(getattr(r, "has_latent", False) and not getattr(r, "store_sigma", True) for r in records)
    return 2 if without_sigma else 1


def encode_bvae(
    records: Sequence[Record],
    decoder: DecoderReference,
    *,
    latent_dtype: LatentDtype = "float32",
    compress_header: bool | None = None,
    short_references: bool | None = None,
    form_variants: bool | None = None,
) -> bytes:
    """Serialise records to the bytes of a ``.bvae`` file (format 2; the preamble states the lowest minor version
    the file needs, §2).

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
    short_references : bool, optional
        Name the decoder and the shared basis by the first 8 bytes of their SHA-256 (format 2.6, §3.1): 48 bytes
        less for a file with basis layers, 24 without, and a file that readers before 2.6 refuse. By default,
        only where ``decoder`` or a record's basis layer is itself a short reference (read from such a file):
        full hashes cannot be written then, and ``False`` is refused.
    form_variants : bool, optional
        Write a layered form that differs from an earlier one in a few numbers (a prior, a μ grid, a first
        vector) as those numbers where that is shorter (format 2.7, §3.2: 4–5 bytes instead of 9; files that
        readers before 2.7 refuse, and only files with several layered forms change). By default, where the
        file has short references: ``short_references=False`` writes a file for readers before 2.6, and with it
        every form in full.

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
    references = [decoder.sha256, *(layer.sha256 for layer in layers if layer is not None)]
    short_only = [ref for ref in references if len(ref) == 2 * SHORT_REFERENCE_BYTES]
    if short_references is None:
        short_references = bool(short_only)
    elif short_only and not short_references:
        raise ValueError(f"full references cannot be written: {short_only[0]} is a short reference (the first 8 bytes "
                         f"of a SHA-256, read from a format 2.6 file); write short references")
    width = 2 * SHORT_REFERENCE_BYTES if short_references else 64
    bases = sorted({layer.sha256[:width] for layer in layers if layer is not None})
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
            if getattr(basis, "prior", None) is not None:  # an entropy-coded layer states its length (2.4, §3.3)
                descriptor += _varint(basis.nbytes)
        if detail is not None:
            descriptor += struct.pack("<d", detail.step) + _varint(detail.nbytes)
        descriptors.append(descriptor)
        payloads.append(payload)
        if record.meta:
            metadata[record.name] = dict(record.meta)
    data = b"".join(payloads)
    flags = (FLAG_BASIS if bases else 0) | (FLAG_SHORT_REFERENCES if short_references else 0)
    header = bytearray(bytes.fromhex(decoder.sha256[:width]) + struct.pack("<HB", latent_dim,
                                                                           _DTYPE_CODES[latent_dtype]))
    if bases:
        header += bytes.fromhex(bases[0])
    table = _form_table(list(forms), short_references if form_variants is None else form_variants)
    variants = any(entry[0] == VARIANT_KIND for entry in table)
    header += bytes([len(forms)]) + b"".join(table)
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
    minor = _minor_needed(records, short_references, variants)
    head = _PREAMBLE.pack(MAGIC, FORMAT_MAJOR, minor, flags, len(header), 0)[:_CRC_COVERED_PREAMBLE]
    crc = zlib.crc32(header, zlib.crc32(head))
    return head + struct.pack("<I", crc) + bytes(header) + data


def write_bvae(
    path: str | os.PathLike[str],
    records: Sequence[Record],
    decoder: DecoderReference,
    *,
    latent_dtype: LatentDtype = "float32",
    overwrite: bool = False,
    short_references: bool | None = None,
) -> int:
    """Write a ``.bvae`` file atomically (see :func:`encode_bvae`, whose ``short_references`` it passes on).

    Returns
    -------
    int
        Size of the written file, in bytes.

    Raises
    ------
    FileExistsError
        ``path`` exists and ``overwrite`` is false.
    """
    data = encode_bvae(records, decoder, latent_dtype=latent_dtype, short_references=short_references)
    with atomic_output(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)
    return len(data)
