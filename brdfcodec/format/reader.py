"""Reading ``.bvae`` files: every field checked, every byte under a CRC (``spec/bvae-format.md`` §3–§4).

A problem is a typed error naming the file.

Part of :mod:`brdfcodec.format.bvae`, which re-exports its names.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from brdfcodec.errors import BvaeChecksumError, BvaeFormatError, UnsupportedVersionError
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
    FLAG_BASIS,
    FLAG_METADATA_ZSTD,
    FLAG_SHORT_REFERENCES,
    FORMAT_MAJOR,
    KNOWN_FLAGS,
    MAGIC,
    MAX_HEADER_BYTES,
    MAX_HEADER_JSON_BYTES,
    MAX_RECORDS,
    PREAMBLE_SIZE,
    BvaeHeader,
    DecoderReference,
    ParsedBvae,
    Record,
    RecordEntry,
    _Form,
)
from brdfcodec.format.form_variants import (
    LAYERED_KIND,
    RESERVED_CHANGE_BITS,
    VARIANT_FIELD_SIZES,
    VARIANT_FIELDS,
    VARIANT_KIND,
    resolve_variant,
    split_layered_form,
)
from brdfcodec.format.layered_record import (
    UnsupportedLayerError,
    latent_values_stored,
    layered_from_payload,
    layers_length,
)
from brdfcodec.format.material_names import MAX_NAME_LENGTH as MAX_NAME_LENGTH  # re-exported
from brdfcodec.format.material_names import check_material_name, name_collision_key
from brdfcodec.format.records import MAX_LATENT_DIM as MAX_LATENT_DIM  # re-exported
from brdfcodec.format.records import GraftRecord, LatentRecord, meta_problem
from brdfcodec.format.strict_json import _check_json_text
from brdfcodec.format.writer import _DETAIL_CODES, _KIND_CODES, _MU_CODES, _SIGMA_CODES
from brdfcodec.io.hashing import SHORT_REFERENCE_BYTES
from brdfcodec.layers.basis import MAX_BASIS_COUNT
from brdfcodec.layers.coded_basis import MAX_MU_STEP_LOG2
from brdfcodec.layers.packed import MAX_TOP_WIDTH

__all__ = ["BvaeReader", "parse_bvae", "read_bvae", "read_header"]

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
    if mu_code not in mus or sigma_code not in sigmas or layer_bits & ~(
            _LAYER_BASIS | _LAYER_DETAIL | _LAYER_PACKED | _LAYER_CODED):
        raise UnsupportedVersionError(
            path, f"{where} stores mu, sigma or layers in a way unknown to this reader (codes {mu_code}, {sigma_code}, "
            f"{layer_bits}); upgrade brdfcodec")
    # A record without a latent (2.1, spec §4.6) stores neither mu nor sigma, and needs a basis layer; a record
    # with a latent may leave sigma out (2.2), and is then allowed to be its base alone (no layer).
    if mus[mu_code] == "none" and sigmas[sigma_code] != "none":
        raise _fail(path, f"{where} stores no mu but a sigma: a record without a latent (mu and sigma 'none') "
                    "stores neither")
    if not layer_bits and not (sigmas[sigma_code] == "none" and mus[mu_code] != "none"):
        raise _fail(path, f"{where}: a layered form holds neither a basis nor a detail layer (only a record "
                    "without a stored sigma may be its base alone)")
    if mus[mu_code] == "none" and not layer_bits & _LAYER_BASIS:
        raise _fail(path, f"{where} stores no latent and no basis layer: a record without a latent needs one")
    if layer_bits & _LAYER_PACKED and not layer_bits & _LAYER_BASIS:
        raise _fail(path, f"{where} packs a basis layer it does not have (layer bit 2 without bit 0)")
    if layer_bits & _LAYER_CODED and (not layer_bits & _LAYER_BASIS or layer_bits & _LAYER_PACKED):
        raise _fail(path, f"{where} entropy-codes a basis layer it does not have, or one it packs (layer bit 3 "
                    "needs bit 0 and excludes bit 2)")
    if mus[mu_code] == "coded" and not layer_bits & _LAYER_CODED:
        raise _fail(path, f"{where} codes mu in an entropy-coded basis layer it does not have (mu 4 needs layer "
                    "bit 3)")
    layers: dict[str, Any] = {}
    if mus[mu_code] is not None:
        layers["mu"] = mus[mu_code]
    if sigmas[sigma_code] is not None:
        layers["sigma"] = sigmas[sigma_code]
    if layer_bits & _LAYER_BASIS:
        first, project = cursor.varint(f"{where}'s basis first"), cursor.varint(f"{where}'s basis projection")
        # §3.2's ranges, checked as the fields are read (§7 step 5), before any later form's kind
        if first >= MAX_BASIS_COUNT:
            raise _fail(path, f"{where}'s basis first is {first}, outside 0 to {MAX_BASIS_COUNT - 1}")
        if project > MAX_BASIS_COUNT:
            raise _fail(path, f"{where}'s basis projection is {project}, outside 0 to {MAX_BASIS_COUNT}")
        if basis_sha is None:
            raise _fail(path, f"{where} has a basis layer, but the header names no shared basis")
        if project and mus[mu_code] == "none":
            raise _fail(path, f"{where} stores no latent but projects its base on {project} basis vectors (a record "
                        "without a latent has no base decode to project: project must be 0)")
        top = 0
        if layer_bits & _LAYER_PACKED:
            top = cursor.u8(f"{where}'s packed top width")
            if not 1 <= top <= MAX_TOP_WIDTH:
                raise _fail(path, f"{where} packs its basis layer with top width {top}, outside 1 to {MAX_TOP_WIDTH}")
        coded = {}
        if layer_bits & _LAYER_CODED:  # format 2.4: the prior's amplitude and decay (spec §4.8)
            coded = {"prior": [cursor.u8(f"{where}'s prior amplitude"), cursor.u8(f"{where}'s prior decay")],
                     "length": 1}
            if mus[mu_code] == "coded":  # format 2.5: the coded μ's grid exponent g, μ = q · 2^−g (spec §4.9)
                g = cursor.u8(f"{where}'s mu step")
                if not 1 <= g <= MAX_MU_STEP_LOG2:
                    raise _fail(path, f"{where} codes mu on the grid 2^-{g}, outside 1 to {MAX_MU_STEP_LOG2}")
                coded["mu_step"] = g
        # as brdfcodec.format.layered_record.layers_entry writes it: ``first``, ``project`` and ``top`` only when
        # not 0
        layers["basis"] = {"sha256": basis_sha, "count": 1, **({"first": first} if first else {}),
                           **({"project": project} if project else {}), **({"top": top} if top else {}), **coded}
    if layer_bits & _LAYER_DETAIL:
        dtypes = {v: k for k, v in _DETAIL_CODES.items()}
        code = cursor.u8(f"{where}'s detail form")
        if code not in dtypes:
            raise UnsupportedVersionError(path, f"{where} has detail form {code}, unknown to this reader; upgrade "
                                          "brdfcodec")
        layers["detail"] = {"transform": "dct3-ycc", "step": 1.0, "dtype": dtypes[code], "length": 1}
    return _Form("layered", (), layers)


#: The variant fields' names in messages (spec §3.2).
_FIELD_NAMES = {"first": "basis first", "project": "basis projection", "top": "packed top width", "prior": "prior",
                "mu_step": "mu step", "detail": "detail form"}


def _parse_variant(path: str, cursor: _Cursor, i: int, written: list[bytes]) -> bytes:
    """A variant (kind 3, since 2.7; spec §3.2) after its kind byte: its base, the fields it changes and their
    values, returned as the form it makes written in full (which the caller then checks as any full form)."""
    where = f"record form {i}"
    base = cursor.varint(f"{where}'s base form")
    if base >= i:
        raise _fail(path, f"{where} is a variant of form {base}, which is not an earlier form")
    if written[base][0] != LAYERED_KIND:
        raise _fail(path, f"{where} is a variant of form {base}, which is not a layered form")
    changes = cursor.u8(f"{where}'s changes")
    if changes & RESERVED_CHANGE_BITS:
        raise UnsupportedVersionError(path, f"{where} changes fields unknown to this reader (bits "
                                      f"0x{changes & RESERVED_CHANGE_BITS:02x}); upgrade brdfcodec")
    if not changes:
        raise _fail(path, f"{where} is a variant of form {base} that changes nothing (the form twice)")
    _, fields = split_layered_form(written[base])
    named = [name for bit, name in enumerate(VARIANT_FIELDS) if changes >> bit & 1]
    absent = [name for name in named if name not in fields]
    if absent:
        raise _fail(path, f"{where} changes the {_FIELD_NAMES[absent[0]]} of form {base}, which has none")
    values: dict[str, bytes] = {}
    for name in named:
        if not VARIANT_FIELD_SIZES[name]:  # a varint
            start = cursor.at
            cursor.varint(f"{where}'s basis {name}")
            values[name] = cursor.data[start : cursor.at]
        else:
            values[name] = cursor.take(VARIANT_FIELD_SIZES[name], f"{where}'s {_FIELD_NAMES[name]}")
        if values[name] == fields[name]:  # a variant names only what differs: one variant of a form on a base
            raise _fail(path, f"{where} sets the {_FIELD_NAMES[name]} of form {base} to the value it has")
    return resolve_variant(written[base], values)


def _parse_form_table(path: str, cursor: _Cursor, count: int, latent_dim: int,
                      basis_sha: str | None) -> tuple[list[_Form], list[bytes]]:
    """The forms (§3.2) and each one's bytes written in full: a variant (since 2.7) is rebuilt from its base
    and checked as the full form it makes, where a full form's fields are checked (§7 step 5)."""
    forms: list[_Form] = []
    written: list[bytes] = []
    for i in range(count):
        start = cursor.at
        if cursor.u8(f"record form {i}'s kind") == VARIANT_KIND:
            full = _parse_variant(path, cursor, i, written)
            forms.append(_parse_form(path, _Cursor(path, full), i, latent_dim, basis_sha))
        else:
            cursor.at = start
            forms.append(_parse_form(path, cursor, i, latent_dim, basis_sha))
            full = cursor.data[start : cursor.at]
        written.append(full)
    return forms, written


def _parse_header(path: str, stored: bytes, preamble_fields: tuple[int, ...], file_size: int) -> BvaeHeader:
    """The binary header (§3): file-level fields, the form table, the record index, the payload CRC, metadata."""
    major, minor, flags, header_length, _ = preamble_fields
    cursor = _Cursor(path, stored)
    # 2.6 (flag bit 2): the decoder and the shared basis named by the first 8 bytes of their SHA-256
    reference = SHORT_REFERENCE_BYTES if flags & FLAG_SHORT_REFERENCES else 32
    sha = cursor.take(reference, "the decoder's SHA-256").hex()
    latent_dim = int.from_bytes(cursor.take(2, "latent_dim"), "little")
    if not 1 <= latent_dim <= MAX_LATENT_DIM:
        raise _fail(path, f"latent_dim {latent_dim} is outside [1, {MAX_LATENT_DIM}]")
    dtype_code = cursor.u8("latent_dtype")
    dtypes = {v: k for k, v in _DTYPE_CODES.items()}
    if dtype_code not in dtypes:
        raise UnsupportedVersionError(path, f"latent dtype code {dtype_code} is not supported (0: float32, 1: float16)")
    latent_dtype = dtypes[dtype_code]
    basis_sha = cursor.take(reference, "the shared basis' SHA-256").hex() if flags & FLAG_BASIS else None
    form_count = cursor.u8("the form count")
    if not form_count:
        raise _fail(path, "the form table is empty")
    forms, written = _parse_form_table(path, cursor, form_count, latent_dim, basis_sha)
    if len(set(written)) != len(written):
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
                if "prior" in layers["basis"]:
                    layers["basis"]["length"] = cursor.varint(f"{label}'s coded basis length")
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
    header = _header_from_handle(name, io.BytesIO(data), len(data))
    return _parse_records(name, header, memoryview(data)[header.records_offset :])


def _parse_records(name: str, header: BvaeHeader, payloads: bytes | memoryview) -> ParsedBvae:
    """Every record from the payloads (the bytes after the header): their CRC-32 (§7 step 8), then each record's
    values (step 9)."""
    _check_payload_crc(name, header, zlib.crc32(payloads))
    records = tuple(_decode_record(name, header, e, bytes(payloads[e.offset : e.offset + e.length]))
                    for e in header.entries)
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
    """Read and verify a whole ``.bvae`` file (the header's and the payloads' CRC-32 are checked).

    The preamble is read first, then the header it declares (at most 16 MB), then exactly the payload bytes the
    header declares: a file that is not a ``.bvae`` file (a device such as ``/dev/zero``, a large sparse file)
    is refused after its first 24 bytes, whatever its size.
    """
    handle, size = _open_checked(path)
    name = os.fspath(path)
    with handle:
        header = _header_from_handle(name, handle, size)
        wanted = header.file_size - header.records_offset
        payloads = _read_exact(handle, wanted)
        if len(payloads) != wanted:
            raise _fail(name, f"truncated: the records need {wanted} bytes, {len(payloads)} could be read")
        if _read_exact(handle, 1):
            raise _fail(name, "trailing bytes after the last record (the file grew while it was read)")
    return _parse_records(name, header, payloads)


class BvaeReader:
    """Random access to the records of a ``.bvae`` file.

    Opening reads the preamble and header, reads the payloads once to
    check their CRC-32 (one for all records, §3), and checks every record's
    values (§7 step 9, before a decoder's checks of step 10); :meth:`read`
    then reads one record's bytes. Use as a context manager, or call
    :meth:`close`.

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
            # §7: every record's values (step 9) are checked before the file is used, so that a reader that opens it
            # for decoding (step 10 next) refuses a file for the same reason as one that reads it whole (info).
            for entry in self.header.entries:
                self._read_entry(entry)
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
        return self._read_entry(self.header.entry(name))

    def _read_entry(self, entry: RecordEntry) -> Record:
        self._handle.seek(self.header.records_offset + entry.offset)
        return _decode_record(os.fspath(self.path), self.header, entry, _read_exact(self._handle, entry.length))

    def read_all(self) -> list[Record]:
        """Every record, in file order."""
        return [self.read(name) for name in self.names]
