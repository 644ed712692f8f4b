"""Mutations of ``.bvae`` files for the fuzz campaign (``bvae bench fuzz``): blind byte changes and field-aware ones.

A field-aware mutation changes one field the header declares (``spec/bvae-format.md`` §2–§3: versions, flags,
latent size and type, forms and their layer fields, the record index, the metadata block) or one value of the
payload, then recomputes the header length and both CRC-32s, so that the mutant reaches the checks behind the
CRCs. Everything here works on bytes and a :class:`random.Random`; nothing reads or writes files.
"""

from __future__ import annotations

import json
import random
import struct
import zlib
from dataclasses import dataclass

__all__ = ["Field", "bvae_fields", "fix_bvae", "mutate_bvae"]

PREAMBLE = 24
_FLAG_ZSTD = 1
_FLAG_BASIS = 2
_FLAG_SHORT_REFERENCES = 4

#: Values worth trying in an unsigned field of each width (limits, off-by-one, bit patterns).
_INTERESTING = {
    1: (0, 1, 2, 3, 4, 7, 8, 15, 16, 24, 25, 127, 128, 254, 255),
    2: (0, 1, 2, 7, 8, 9, 255, 256, 1023, 1024, 1025, 32767, 32768, 65535),
    4: (0, 1, 2, 3, 4, 7, 255, 256, 65535, 2**24, 16_777_216, 16_777_217, 2**31 - 1, 2**31, 2**32 - 1),
}
_VARINTS = (0, 1, 2, 3, 7, 8, 9, 20, 74, 75, 76, 127, 128, 240, 241, 255, 4095, 4096, 4097, 16383, 16384,
            65535, 65536, 65537, 1_048_576, 1_048_577, 67_108_864, 67_108_865, 2**28 - 1)
_FLOATS = (0.0, -0.0, 1e-5, 99.99, 100.0, 100.01, 1e-300, 5e-324, -1.0, 1e300, 1.7976931348623157e308,
           float("inf"), float("-inf"), float("nan"))
_JSON_VALUES = ("null", "true", "0", "-1", "1e999", "-1e999", "9007199254740993", "NaN", "Infinity", '"x"',
                '""', "[]", "{}", '"\\ud800"', '"\\u0000"', "1" * 400, '[' * 70 + ']' * 70, '{"a":1,"a":2}',
                '"' + "\\\"" * 200 + '"')


@dataclass(frozen=True)
class Field:
    """One field of a ``.bvae`` file: its name, where its bytes are (file offsets, end excluded) and its type
    (``"u8"``, ``"u16"``, ``"u32"``, ``"varint"``, ``"f64"``, ``"bytes"``, ``"metadata"``)."""

    name: str
    start: int
    end: int
    kind: str


class _Cursor:
    def __init__(self, data: bytes, at: int, end: int) -> None:
        self.data, self.at, self.end = data, at, end
        self.fields: list[Field] = []

    def take(self, name: str, size: int, kind: str) -> bytes:
        if self.at + size > self.end:
            raise IndexError(name)
        self.fields.append(Field(name, self.at, self.at + size, kind))
        self.at += size
        return self.data[self.at - size : self.at]

    def varint(self, name: str) -> int:
        value, start = 0, self.at
        for shift in range(0, 35, 7):
            if self.at >= self.end:
                raise IndexError(name)
            byte = self.data[self.at]
            self.at += 1
            value |= (byte & 0x7F) << shift
            if not byte & 0x80:
                self.fields.append(Field(name, start, self.at, "varint"))
                return value
        raise IndexError(name)


def bvae_fields(data: bytes) -> list[Field]:
    """The fields of a ``.bvae`` file, as far as its bytes parse (a prefix for a malformed file).

    The payload is listed as one field per record (``"payload"``) when the index parses; the payload CRC-32
    field is ``"payload_crc32"`` and the metadata block ``"metadata"``."""
    cur = _Cursor(data, 0, len(data))
    try:
        for name, size, kind in (("magic", 8, "bytes"), ("major", 2, "u16"), ("minor", 2, "u16"),
                                 ("flags", 4, "u32"), ("header_length", 4, "u32"), ("header_crc32", 4, "u32")):
            cur.take(name, size, kind)
        flags, length = struct.unpack_from("<II", data, 12)
        cur.end = min(len(data), PREAMBLE + length)
        reference = 8 if flags & _FLAG_SHORT_REFERENCES else 32  # format 2.6: short references (spec §3.1)
        cur.take("decoder", reference, "bytes")
        cur.take("latent_dim", 2, "u16")
        cur.take("latent_dtype", 1, "u8")
        if flags & _FLAG_BASIS:
            cur.take("basis", reference, "bytes")
        forms = []
        for f in range(cur.take("form_count", 1, "u8")[0]):
            kind = cur.take(f"form{f}.kind", 1, "u8")[0]
            layers = 0
            if kind == 1:
                for d in range(cur.varint(f"form{f}.graft_k")):
                    cur.varint(f"form{f}.graft_dim{d}")
            elif kind == 2:
                mu = cur.take(f"form{f}.mu", 1, "u8")[0]
                cur.take(f"form{f}.sigma", 1, "u8")
                layers = cur.take(f"form{f}.layers", 1, "u8")[0]
                if layers & 1:
                    cur.varint(f"form{f}.first")
                    cur.varint(f"form{f}.project")
                    if layers & 4:
                        cur.take(f"form{f}.top", 1, "u8")
                    if layers & 8:
                        cur.take(f"form{f}.prior", 2, "bytes")
                if mu == 4:  # a coded μ's grid exponent (format 2.5, spec §4.9)
                    cur.take(f"form{f}.mu_step", 1, "u8")
                if layers & 2:
                    cur.take(f"form{f}.detail_form", 1, "u8")
            elif kind == 3:  # a variant of an earlier layered form (format 2.7, spec §3.2): its layers are the base's
                layers = forms[cur.varint(f"form{f}.base")]
                changes = cur.take(f"form{f}.changes", 1, "u8")[0]
                for bit, (field, size) in enumerate((("first", 0), ("project", 0), ("top", 1), ("prior", 2),
                                                     ("mu_step", 1), ("detail_form", 1))):
                    if changes >> bit & 1:
                        if size:
                            cur.take(f"form{f}.{field}", size, "u8" if size == 1 else "bytes")
                        else:
                            cur.varint(f"form{f}.{field}")
            forms.append(layers)
        for r in range(cur.varint("record_count")):
            cur.take(f"record{r}.name", cur.varint(f"record{r}.name_length"), "bytes")
            layers = forms[cur.take(f"record{r}.form", 1, "u8")[0]]
            if layers & 1:
                cur.varint(f"record{r}.count")
                if layers & 8:
                    cur.varint(f"record{r}.basis_length")
            if layers & 2:
                cur.take(f"record{r}.step", 8, "f64")
                cur.varint(f"record{r}.detail_length")
        cur.take("payload_crc32", 4, "u32")
        cur.fields.append(Field("metadata", cur.at, cur.end, "metadata"))
        if cur.end < len(data):
            cur.fields.append(Field("payload", cur.end, len(data), "payload"))
    except (IndexError, struct.error):
        pass
    return cur.fields


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def fix_bvae(data: bytes, *, payload_crc: bool = True) -> bytes:
    """The file with its payload CRC-32 (where the index parses far enough to find it) and its header CRC-32
    recomputed."""
    out = bytearray(data)
    if len(out) < PREAMBLE:
        return bytes(out)
    fields = {f.name: f for f in bvae_fields(bytes(out))}
    records = PREAMBLE + struct.unpack_from("<I", out, 16)[0]
    if payload_crc and "payload_crc32" in fields and records <= len(out):
        crc = fields["payload_crc32"]
        struct.pack_into("<I", out, crc.start, zlib.crc32(bytes(out[records:])))
    if records <= len(out):
        struct.pack_into("<I", out, 20, zlib.crc32(bytes(out[PREAMBLE:records]), zlib.crc32(bytes(out[:20]))))
    return bytes(out)


def _replace(data: bytes, field: Field, new: bytes) -> bytes:
    """Replace a field's bytes; a header field of another length moves the header length with it."""
    out = bytearray(data[: field.start] + new + data[field.end :])
    if field.start >= PREAMBLE and field.kind != "payload" and len(out) >= PREAMBLE:
        length = struct.unpack_from("<I", out, 16)[0] + len(new) - (field.end - field.start)
        if 0 <= length < 2**32:
            struct.pack_into("<I", out, 16, length)
    return bytes(out)


def _field_value(field: Field, old: bytes, rng: random.Random) -> bytes:
    size = field.end - field.start
    if field.kind in ("u8", "u16", "u32"):
        if rng.random() < 0.7:
            value = rng.choice(_INTERESTING[size])
        else:
            value = int.from_bytes(old, "little") ^ (1 << rng.randrange(8 * size))
        return value.to_bytes(size, "little")
    if field.kind == "varint":
        if rng.random() < 0.15:  # not minimal, or five bytes long
            return rng.choice((b"\x80\x00", b"\x81\x00", b"\x80\x80\x80\x80\x00", b"\xff\xff\xff\xff\x7f"))
        old_value = sum((b & 0x7F) << (7 * i) for i, b in enumerate(old))
        value = rng.choice(_VARINTS) if rng.random() < 0.7 else max(0, old_value + rng.randint(-3, 3))
        return _varint(value)
    if field.kind == "f64":
        return struct.pack("<d", rng.choice(_FLOATS))
    # bytes: names, hashes, magic
    new = bytearray(old)
    if new and rng.random() < 0.6:
        for _ in range(rng.randint(1, 3)):
            new[rng.randrange(len(new))] = rng.choice((0, 0x2F, 0x2E, 0x5C, 0x80, 0xC0, 0xEF, 0xFF,
                                                       rng.randrange(256)))
        return bytes(new)
    return bytes(rng.choice((b"", b".", b"..", b"a/b", "\ufeffa".encode(), b"\xed\xa0\x80", "CON".encode(),
                             "COM\u00b9".encode(), "\u202egnp".encode(), b"a" * 241, b"\x00", old + old)))


def _mutate_metadata(text: bytes, rng: random.Random) -> bytes:
    """A change to the metadata block's JSON text (a value replaced, a key duplicated, nesting, truncation)."""
    how = rng.random()
    if how < 0.45 and text:
        try:
            value = json.loads(text)
        except ValueError:
            value = None
        if isinstance(value, dict) and value:
            key = rng.choice(sorted(value))
            inner = value[key]
            if isinstance(inner, dict) and inner and rng.random() < 0.7:
                sub = rng.choice(sorted(inner))
                body = json.dumps({**value, key: {**inner, sub: "@@"}})
            else:
                body = json.dumps({**value, key: "@@"})
            return body.replace('"@@"', rng.choice(_JSON_VALUES)).encode()
    if how < 0.6:
        return b'{"records": {"' + rng.choice((b"a", b"\xff", b"")) + b'": ' + rng.choice(_JSON_VALUES).encode() + b"}}"
    if how < 0.7:
        return b"{}" if rng.random() < 0.5 else b""
    if how < 0.85 and text:
        out = bytearray(text)
        out[rng.randrange(len(out))] = rng.choice(b'{}[]",:\\0 \xff')
        return bytes(out)
    return text[: rng.randrange(len(text) + 1)]


def _metadata_change(data: bytes, field: Field, rng: random.Random) -> bytes:
    import zstandard

    stored = data[field.start : field.end]
    compressed = bool(struct.unpack_from("<I", data, 12)[0] & _FLAG_ZSTD)
    text = stored
    if compressed:
        try:
            text = zstandard.ZstdDecompressor().decompress(stored, max_output_size=1 << 20)
        except zstandard.ZstdError:
            text = b""
    new = _mutate_metadata(text, rng)
    if compressed or rng.random() < 0.1:
        if not compressed:  # compress it now, flag set
            out = bytearray(data)
            struct.pack_into("<I", out, 12, struct.unpack_from("<I", out, 12)[0] | _FLAG_ZSTD)
            data = bytes(out)
        params = {"write_content_size": rng.random() < 0.9}
        new = zstandard.ZstdCompressor(level=1, **params).compress(new)
        if rng.random() < 0.1:
            new += rng.choice((b"\x00", new, zstandard.ZstdCompressor().compress(b"{}")))
    return _replace(data, field, new)


def _payload_change(data: bytes, field: Field, rng: random.Random) -> bytes:
    """Values of the payload: float32/float16 specials, int8 extremes, whole bytes."""
    out = bytearray(data)
    span = field.end - field.start
    if span <= 0:
        return data
    for _ in range(rng.choice((1, 1, 2, 4))):
        at = field.start + rng.randrange(span)
        how = rng.random()
        if how < 0.3 and at + 4 <= len(out):
            struct.pack_into("<f", out, at, rng.choice((float("nan"), float("inf"), -1.0, 0.0, 3.4e38, 1e-45,
                                                        -3.4e38, 1e19, 1e23)))
        elif how < 0.5 and at + 2 <= len(out):
            out[at : at + 2] = rng.choice((b"\x00\x7c", b"\x00\x7e", b"\xff\x7b", b"\x01\x00", b"\x00\x00",
                                           b"\x00\xfc", b"\x00\x80"))
        else:
            out[at] = rng.choice((0x00, 0x7F, 0x80, 0x81, 0xFF, out[at] ^ 0xFF, rng.randrange(256)))
    return bytes(out)


def mutate_bvae(seed: bytes, rng: random.Random, other: bytes | None = None) -> tuple[bytes, str]:
    """One mutant of a ``.bvae`` seed and the name of the mutation.

    Parameters
    ----------
    seed : bytes
        A valid file.
    rng : random.Random
        The only source of randomness: the same state gives the same mutant.
    other : bytes, optional
        A second valid file, for splices.

    Returns
    -------
    data : bytes
        The mutant (CRCs recomputed for the field-aware mutations, most of the time).
    how : str
        The mutation's name: ``"bit flip"``, ``"byte set"``, ``"truncate"``, ``"insert"``, ``"delete"``,
        ``"splice"``, ``"field:NAME"`` (NAME without its record or form number), ``"payload value"``.
    """
    data = seed
    fields = bvae_fields(seed)
    how = rng.random()
    if how < 0.05:
        return seed[: rng.randrange(len(seed))], "truncate"
    if how < 0.1:
        at = rng.randrange(len(seed))
        out = bytearray(seed)
        out[at] ^= 1 << rng.randrange(8)
        return bytes(out), "bit flip"
    if how < 0.14:
        at = rng.randrange(len(seed) + 1)
        extra = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        return fix_bvae(seed[:at] + extra + seed[at:]), "insert"
    if how < 0.18:
        at = rng.randrange(len(seed))
        return fix_bvae(seed[:at] + seed[at + rng.randint(1, 8) :]), "delete"
    if how < 0.24 and other is not None:  # header of one file, payload of the other, or a cut of both
        theirs = {f.name: f for f in bvae_fields(other)}
        mine = {f.name: f for f in fields}
        if "payload" in mine and "payload" in theirs and rng.random() < 0.6:
            data = seed[: mine["payload"].start] + other[theirs["payload"].start :]
        else:
            data = seed[: rng.randrange(len(seed) + 1)] + other[rng.randrange(len(other) + 1) :]
        return fix_bvae(data), "splice"
    if how < 0.3:
        out = bytearray(seed)
        for _ in range(rng.randint(1, 4)):
            out[rng.randrange(PREAMBLE, len(out))] = rng.choice((0, 0xFF, 0x7F, 0x80, rng.randrange(256)))
        return fix_bvae(bytes(out)), "byte set"
    payload = [f for f in fields if f.kind == "payload"]
    if how < 0.48 and payload:
        return fix_bvae(_payload_change(seed, payload[0], rng)), "payload value"
    choices = [f for f in fields if f.kind not in ("payload",) and f.name not in ("header_crc32", "payload_crc32")]
    field = rng.choice(choices)
    name = field.name.split(".", 1)[-1] if "." in field.name else field.name
    if field.kind == "metadata":
        data = _metadata_change(seed, field, rng)
    else:
        data = _replace(seed, field, _field_value(field, seed[field.start : field.end], rng))
    if field.name == "header_length" or rng.random() < 0.05:
        return data, f"field:{name} (CRCs as they were)"
    return fix_bvae(data), f"field:{name}"
