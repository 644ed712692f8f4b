"""Mutations of RGL ``.bsdf`` headers and of model folders for the fuzz campaign (``bvae bench fuzz``).

A ``.bsdf`` mutant changes a field the tensor file's header declares (its shape, type code, offset, number of
dimensions, name), the version or field count, or a value of a field's data, or truncates the file
(``spec/conventions.md`` §9.1 names the fields the reader checks). A model-folder mutant replaces ``model.json``
(a value of its schema, a key, its bytes) or one weight file's safetensors header (a tensor's dtype, shape or
offsets, the stored config, the header length); with most weight changes the manifest's SHA-256 of that file is
updated too, so that the mutant reaches the checks behind the hash (``spec/model.md`` §3). Bytes in, bytes out.
"""

from __future__ import annotations

import hashlib
import json
import random
import struct

__all__ = ["WEIGHT_HASH_KEYS", "mutate_bsdf", "mutate_model_folder", "tensor_fields"]

_MAGIC_LENGTH = 12
_SHAPE_VALUES = (0, 1, 2, 3, 7, 8, 90, 2**31, 2**32, 2**32 + 1, 2**62, 2**63, 2**64 - 1)

#: The manifest key holding each weight file's SHA-256.
WEIGHT_HASH_KEYS = {"decoder.safetensors": "decoder_sha256", "encoder.safetensors": "encoder_sha256",
                    "basis.safetensors": "basis_sha256"}

_HOSTILE = (None, True, False, 0, -1, 1, 2, 0.5, -0.0, 1e308, -1e308, 2**53 + 1, 2**63, 10**30, 40_000_000, 3000,
            "", "x", "8", "group", "none", [], [0], [-5], [1.5], [40_000_000], ["a"], [8, 8], [64] * 40, {},
            {"a": 1}, "a" * 10_000)
_JSON_TOKENS = ("NaN", "Infinity", "-Infinity", "1e999", "[" * 200 + "]" * 200, '"\\ud800"', "00", "+1")


def tensor_fields(data: bytes) -> list[tuple[int, int]]:
    """(position of each field's ``ndim``, ``ndim``) in a tensor file's header, as far as it parses."""
    out: list[tuple[int, int]] = []
    if len(data) < 18:
        return out
    at = 18
    try:
        for _ in range(struct.unpack_from("<I", data, 14)[0]):
            length = struct.unpack_from("<H", data, at)[0]
            at += 2 + length
            ndim = struct.unpack_from("<H", data, at)[0]
            if at + 11 + 8 * ndim > len(data):
                break
            out.append((at, ndim))
            at += 11 + 8 * ndim
    except struct.error:
        pass
    return out


def mutate_bsdf(seed: bytes, rng: random.Random) -> tuple[bytes, str]:
    """One mutant of a valid RGL ``.bsdf`` file, and the mutation's name."""
    data = bytearray(seed)
    fields = tensor_fields(seed)
    at, ndim = rng.choice(fields)
    how = rng.random()
    if how < 0.3 and ndim:
        value = rng.choice(_SHAPE_VALUES) if rng.random() < 0.7 else rng.randrange(2**64)
        struct.pack_into("<Q", data, at + 11 + 8 * rng.randrange(ndim), value)
        return bytes(data), "shape"
    if how < 0.42:
        data[at + 2] = rng.randrange(256) if rng.random() < 0.3 else rng.randrange(13)
        return bytes(data), "type code"
    if how < 0.54:
        offset = struct.unpack_from("<Q", data, at + 3)[0]
        value = rng.choice((0, 8, 17, len(data) - 4, len(data), 2**63, rng.randrange(2**64),
                            offset + rng.randint(-9, 9), fields[0][0]))
        struct.pack_into("<Q", data, at + 3, max(0, value))
        return bytes(data), "offset"
    if how < 0.6:
        struct.pack_into("<H", data, at, rng.choice((0, 1, 2, 3, 4, 5, 6, 9, 65535)))
        return bytes(data), "ndim"
    if how < 0.65:
        data[rng.randrange(_MAGIC_LENGTH, 18)] = rng.randrange(256)
        return bytes(data), "version or count"
    if how < 0.7:  # a field's name (the reader looks fields up by name)
        name_at = _name_start(seed, at)
        if name_at is not None and name_at < at:
            data[rng.randrange(name_at, at)] = rng.choice((0x00, 0x5F, 0x61, 0xFF, rng.randrange(256)))
        return bytes(data), "field name"
    if how < 0.75:
        return bytes(data[: rng.randrange(len(data))]), "truncate"
    if how < 0.92:  # a value in a field's data: NaN, infinities, negative, huge, tiny
        offset = struct.unpack_from("<Q", data, at + 3)[0]
        if 0 < offset < len(data) - 4:
            end = len(data) - 4
            for _ in range(rng.choice((1, 1, 8, 64))):
                position = rng.randrange(offset, end)
                struct.pack_into("<f", data, position, rng.choice((float("nan"), float("inf"), float("-inf"), -1.0,
                                                                   3e38, 0.0, 1e-38, 1e-45, 1e11)))
        return bytes(data), "data value"
    last = fields[-1][0] + 11 + 8 * fields[-1][1]
    for _ in range(rng.randint(1, 4)):
        data[rng.randrange(_MAGIC_LENGTH, last)] = rng.randrange(256)
    return bytes(data), "header bytes"


def _name_start(seed: bytes, ndim_at: int) -> int | None:
    """Where the name of the field whose ``ndim`` is at ``ndim_at`` starts."""
    at = 18
    for _ in range(struct.unpack_from("<I", seed, 14)[0]):
        length = struct.unpack_from("<H", seed, at)[0]
        if at + 2 + length == ndim_at:
            return at + 2
        at += 2 + length
        ndim = struct.unpack_from("<H", seed, at)[0]
        at += 11 + 8 * ndim
    return None


# --------------------------------------------------------------------------- model folders


def _paths(value: object, prefix: tuple = ()) -> list[tuple]:
    """Every key path of a JSON value (lists: their first items only, to keep the choice balanced)."""
    out = [prefix] if prefix else []
    if isinstance(value, dict):
        for key, inner in value.items():
            out += _paths(inner, (*prefix, key))
    elif isinstance(value, list):
        for index, inner in enumerate(value[:3]):
            out += _paths(inner, (*prefix, index))
    return out


def _set(value: object, path: tuple, new: object, delete: bool = False) -> None:
    for key in path[:-1]:
        value = value[key]  # type: ignore[index]
    if delete and isinstance(value, dict):
        del value[path[-1]]
    else:
        value[path[-1]] = new  # type: ignore[index]


def _mutate_json_text(text: bytes, rng: random.Random, weights: float) -> tuple[bytes, str]:
    """A change to a JSON object's text: a value (``weights``: how often under ``config``), a key, raw bytes."""
    document = json.loads(text)
    how = rng.random()
    if how < 0.7:
        paths = _paths(document)
        config = [p for p in paths if p[0] == "config"]
        path = rng.choice(config if config and rng.random() < weights else paths)
        if rng.random() < 0.12:
            _set(document, path, None, delete=True)
            return json.dumps(document).encode(), f"delete {path[0]}"
        new = rng.choice(_HOSTILE)
        _set(document, path, new)
        body = json.dumps(document).encode()
        if rng.random() < 0.1:
            body = body.replace(json.dumps(new).encode(), rng.choice(_JSON_TOKENS).encode(), 1)
        return body, f"value {path[0]}" + (f".{path[1]}" if len(path) > 1 and path[0] == "config" else "")
    if how < 0.8:
        document[rng.choice(("extra", "config", "name", "\u0000", "__proto__"))] = rng.choice(_HOSTILE)
        return json.dumps(document).encode(), "key"
    out = bytearray(text)
    if how < 0.9:
        for _ in range(rng.randint(1, 3)):
            out[rng.randrange(len(out))] = rng.choice(b'{}[]",:0-.e\\ \xff')
        return bytes(out), "json bytes"
    return bytes(out[: rng.randrange(len(out) + 1)]), "json truncate"


def _mutate_safetensors(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """A change to a safetensors file's header (its JSON, or the length before it); the data stays."""
    length = struct.unpack_from("<Q", data, 0)[0]
    header, body = data[8 : 8 + length], data[8 + length :]
    how = rng.random()
    if how < 0.1:
        value = rng.choice((0, 1, length - 1, length + 1, len(data), 2**31, 2**63, 2**64 - 1))
        return struct.pack("<Q", value) + data[8:], "safetensors length"
    document = json.loads(header)
    names = [k for k in document if k != "__metadata__"]
    if how < 0.7 and names:
        name = rng.choice(names)
        entry = document[name]
        part = rng.choice(("dtype", "shape", "data_offsets", "entry"))
        if part == "dtype":
            entry["dtype"] = rng.choice(("F16", "F64", "BF16", "I8", "U8", "I64", "BOOL", "F8_E4M3", "X", 1))
        elif part == "shape":
            shape = list(entry["shape"])
            if shape and rng.random() < 0.7:
                shape[rng.randrange(len(shape))] = rng.choice((0, 1, 2, -1, 2**31, 2**63, 1.5, "a"))
            else:
                shape = rng.choice(([], [0], shape[::-1], [*shape, 1], shape[:-1]))
            entry["shape"] = shape
        elif part == "data_offsets":
            start, end = entry["data_offsets"]
            entry["data_offsets"] = rng.choice(([end, start], [start, end + 4], [start - 4, end - 4] if start >= 4
                                                else [0, 0], [0, len(body) + 8], [start, 2**63], [start]))
        else:
            document[name] = rng.choice((None, [], "x", {}, {"dtype": "F32"}))
        how_name = f"tensor {part}"
    elif how < 0.85 and "__metadata__" in document:
        meta = document["__metadata__"]
        key = rng.choice(sorted(meta))
        if key == "config" and rng.random() < 0.8:
            text, inner = _mutate_json_text(meta[key].encode(), rng, 1.0)
            meta[key] = text.decode("utf-8", "replace")
            how_name = f"stored config {inner}"
        else:
            meta[key] = rng.choice(("", "x", "{}", "[]", "null", "1e999"))
            how_name = f"metadata {key}"
        if rng.random() < 0.1:
            document["__metadata__"] = rng.choice(([], {"config": 1}, "x"))
    else:
        extra = rng.choice(({"dtype": "F32", "shape": [1], "data_offsets": [0, 4]},
                            {"dtype": "F32", "shape": [10**6], "data_offsets": [0, 4 * 10**6]}))
        document[rng.choice(("extra.weight", names[0] if names else "x"))] = extra
        how_name = "tensor added"
    new = json.dumps(document).encode()
    new += b" " * (-len(new) % 8)
    return struct.pack("<Q", len(new)) + new + body, f"safetensors {how_name}"


def mutate_model_folder(files: dict[str, bytes], rng: random.Random) -> tuple[dict[str, bytes], str]:
    """A mutant of a valid model folder: the files it replaces (name → bytes) and the mutation's name.

    Parameters
    ----------
    files : dict of str to bytes
        ``model.json`` and the weight files (``decoder.safetensors``, ``encoder.safetensors``,
        ``basis.safetensors``) of a valid folder; files absent here are not mutated.
    rng : random.Random
        The only source of randomness.
    """
    manifest = files["model.json"]
    weights = [name for name in WEIGHT_HASH_KEYS if name in files]
    if rng.random() < 0.55 or not weights:
        text, how = _mutate_json_text(manifest, rng, 0.6)
        return {"model.json": text}, f"model.json {how}"
    name = rng.choice(weights)
    data, how = _mutate_safetensors(files[name], rng)
    changed = {name: data}
    if rng.random() < 0.85:  # the manifest names the new file: the checks behind the hash run
        document = json.loads(manifest)
        document[WEIGHT_HASH_KEYS[name]] = hashlib.sha256(data).hexdigest()
        changed["model.json"] = json.dumps(document, indent=1).encode()
        how += ", hash updated"
    return changed, f"{name.split('.')[0]} {how}"
