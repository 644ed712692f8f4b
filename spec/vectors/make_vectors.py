"""Generate the conformance vectors of ``spec/bvae-format.md`` (§9) and their ``manifest.json``.

Run from the repository root: ``python spec/vectors/make_vectors.py`` (writes
into ``spec/vectors/``), or ``python spec/vectors/make_vectors.py OUT_DIR``.
Re-run it whenever the shipped model changes: the reference-decode vectors
name the shipped decoder and its shared basis, read from its ``model.json``.

Valid files come from the reference writer (one, ``metadata-empty``, is
written by hand); invalid files are built byte by byte here (binary header,
JSON metadata, zstandard frame, CRC-32s and preamble written by hand), so
that each breaks exactly one rule, or exactly the two rules whose precedence
§7 settles. The expected decoder values are measured with the shipped model
and stored with the tolerance §9 states.
"""

from __future__ import annotations

import json
import struct
import sys
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.format.bvae import DecoderReference, GraftRecord, LatentRecord, encode_bvae
from brdfcodec.models.manifest import load_manifest
from brdfcodec.models.registry import package_model_folder

HERE = Path(__file__).resolve().parent
MAGIC = b"\x89BVAE\r\n\x1a"
#: The vectors' model: the first default, ``bvae-nbrdf-proxy-small-v1``, which the package keeps so that its
#: files decode (``brdfcodec/data/models/nbrdf-proxy-small-v1``); the vectors were made with it.
SHIPPED_FOLDER = package_model_folder("nbrdf-proxy-small-v1")
_SHIPPED = load_manifest(SHIPPED_FOLDER)
#: That model's decoder.
SHIPPED_DECODER = DecoderReference(_SHIPPED.decoder_sha256, _SHIPPED.name)
TEST_DECODER = DecoderReference("ab" * 32, "conformance-test-decoder")
#: SHA-256 of the shipped model's shared basis (``basis.safetensors``).
SHIPPED_BASIS = str(_SHIPPED.basis_sha256)
#: Relative and absolute tolerance of expected decoded values (stored MERL units).
DECODE_RTOL = 1e-3
DECODE_ATOL = 1e-6
#: Table entries [channel, θh bin, θd bin, φd bin] whose decoded values the manifest pins.
REFERENCE_ENTRIES = [
    [0, 0, 0, 0], [1, 0, 0, 0], [2, 0, 0, 0],
    [0, 10, 20, 90], [1, 45, 45, 45], [2, 89, 10, 179],
    [0, 30, 60, 9], [1, 30, 60, 13], [2, 5, 85, 100],
    [0, 60, 30, 171], [1, 89, 89, 90], [2, 20, 40, 0],
]


# --------------------------------------------------------------------------- a writer independent of the library


def canonical(value: dict[str, Any]) -> bytes:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode("utf-8")


def varint(value: int) -> bytes:
    """LEB128 (§2.1)."""
    out = bytearray()
    while True:
        out.append((value & 0x7F) | (0x80 if value >> 7 else 0))
        value >>= 7
        if not value:
            return bytes(out)


def latent_form() -> bytes:
    return b"\x00"


def graft_form(dims: list[int]) -> bytes:
    return b"\x01" + varint(len(dims)) + b"".join(varint(d) for d in dims)


def layered_form(mu: int = 0, sigma: int = 0, *, basis: tuple[int, int] | None = None, detail: int | None = None,
                 layer_bits: int | None = None, top: int | None = None) -> bytes:
    """A layered form (§3.2): mu and sigma codes, basis (first, project), detail code, a packed basis layer's top
    width (since 2.3); ``layer_bits`` overrides the layer bits."""
    bits = (1 if basis is not None else 0) | (2 if detail is not None else 0) | (4 if top is not None else 0)
    out = bytes([2, mu, sigma, bits if layer_bits is None else layer_bits])
    if basis is not None:
        out += varint(basis[0]) + varint(basis[1])
    if top is not None:
        out += bytes([top])
    if detail is not None:
        out += bytes([detail])
    return out


def descriptor(name: str | bytes, form: int, *, count: int | None = None, step: float | None = None,
               detail_length: int | None = None) -> bytes:
    raw = name.encode("utf-8") if isinstance(name, str) else name
    out = varint(len(raw)) + raw + bytes([form])
    if count is not None:
        out += varint(count)
    if step is not None:
        out += struct.pack("<d", step) + varint(detail_length or 0)
    return out


def header(forms: list[bytes], descriptors: list[bytes], payload: bytes, *, dim: int = 2, dtype: int = 0,
           decoder: str = TEST_DECODER.sha256, basis: str | None = None, metadata: bytes = b"",
           record_count: bytes | None = None) -> bytes:
    """The binary header (§3): file fields, form table, index, payload CRC, metadata block."""
    out = bytes.fromhex(decoder) + struct.pack("<HB", dim, dtype) + (bytes.fromhex(basis) if basis else b"")
    out += bytes([len(forms)]) + b"".join(forms)
    out += (varint(len(descriptors)) if record_count is None else record_count) + b"".join(descriptors)
    return out + struct.pack("<I", zlib.crc32(payload)) + metadata


def assemble(stored: bytes, payload: bytes, *, flags: int = 0, major: int = 2, minor: int = 1,
             crc_flags: int | None = None) -> bytes:
    """Preamble + header + payload; ``crc_flags`` computes the CRC over other flags (a flipped bit)."""
    def head(f: int) -> bytes:
        return MAGIC + struct.pack("<HHII", major, minor, f, len(stored))

    crc = zlib.crc32(stored, zlib.crc32(head(flags if crc_flags is None else crc_flags)))
    return head(flags) + struct.pack("<I", crc) + stored + payload


def zstd(data: bytes) -> bytes:
    import zstandard

    return zstandard.ZstdCompressor(level=19, write_content_size=True).compress(data)


def f32(*values: float) -> bytes:
    return np.array(values, dtype="<f4").tobytes()


def f16(value: float) -> bytes:
    return np.float16(value).astype("<f2").tobytes()


def invalid_vectors() -> dict[str, tuple[bytes, str, str]]:
    """name -> (file bytes, error class, what is wrong)."""
    good = f32(0.5, -1.0, 0.25, 0.5)
    out: dict[str, tuple[bytes, str, str]] = {}

    def add(name: str, data: bytes, error: str, why: str) -> None:
        out[name] = (data, error, why)

    def one(name: str | bytes = "a", payload: bytes = good, form: bytes = latent_form(), *, flags: int = 0,
            metadata: bytes = b"", **fields: Any) -> bytes:
        """A file of one record (by default a latent record 'a', D = 2)."""
        return assemble(header([form], [descriptor(name, 0, **fields)], payload, metadata=metadata), payload,
                        flags=flags)

    def with_meta(meta: Any, *, top: dict[str, Any] | None = None, flags: int = 0) -> bytes:
        block = canonical({"records": {"a": meta}, **(top or {})})
        return one(metadata=block, flags=flags)

    valid = one()
    add("bad-magic", b"\x89BVAF" + valid[5:], "malformed", "wrong magic number")
    add("truncated-preamble", valid[:20], "malformed", "shorter than the 24-byte preamble")
    add("truncated-record", valid[:-1], "malformed", "the last record is one byte short")
    add("trailing-bytes", valid + b"\x00", "malformed", "one byte after the last record")
    flipped = bytearray(valid)
    flipped[24 + 5] ^= 0x01
    add("header-crc", bytes(flipped), "checksum", "one bit of the decoder hash flipped")
    flipped = bytearray(valid)
    flipped[-1] ^= 0x80
    add("record-crc", bytes(flipped), "checksum", "one payload bit flipped (payload CRC-32)")
    stored = header([latent_form()], [descriptor("a", 0)], good)
    add("flag-bit-flipped", assemble(stored, good, flags=8, crc_flags=0), "checksum",
        "flag bit 3 set by corruption (CRC over the original flags): checksum wins over unsupported (§7)")
    add("unknown-flag", assemble(stored, good, flags=8), "unsupported", "flag bit 3 set, CRC valid")
    add("short-references-over-full-hashes", assemble(stored, good, flags=4, minor=6), "malformed",
        "flag bit 2 (short references, since 2.6) over a header that holds the full 32-byte hash: read as 8 bytes, "
        "latent_dim is then the hash's bytes 8-9 (43947)")
    short = header([latent_form()], [descriptor("a", 0)], good, decoder=TEST_DECODER.sha256[:16])
    add("short-references-truncated", assemble(short, good, flags=4, minor=6)[:-1], "malformed",
        "a valid file with short references (2.6), one byte short")
    add("major-version-3", assemble(stored, good, major=3), "unsupported", "major version 3")
    add("major-version-1", assemble(stored, good, major=1, minor=6), "unsupported",
        "major version 1 (the development format): refused, whatever follows")
    add("unknown-kind", one(form=b"\x04"), "unsupported", "record kind code 4")
    add("unknown-dtype", assemble(header([latent_form()], [descriptor("a", 0)], good, dtype=2), good),
        "unsupported", "latent_dtype code 2")
    add("latent-dim-zero", assemble(header([latent_form()], [descriptor("a", 0)], b"", dim=0), b""), "malformed",
        "latent_dim 0")
    add("header-ends-in-form-table", assemble(header([latent_form()], [descriptor("a", 0)], good)[:36], good),
        "malformed", "a header (CRC valid) that ends inside the form table")
    add("record-count-zero", assemble(header([latent_form()], [], b""), b""), "malformed", "no record")
    add("form-count-zero", assemble(header([], [descriptor("a", 0)], good), good), "malformed", "no form")
    add("form-index", assemble(header([latent_form()], [descriptor("a", 1)], good), good), "malformed",
        "a record names form 1 of a table of one")
    add("form-unused", assemble(header([latent_form(), graft_form([1])], [descriptor("a", 0)], good), good),
        "malformed", "a form (graft) that no record uses")
    add("form-twice", assemble(header([latent_form(), latent_form()], [descriptor("a", 0), descriptor("b", 1)],
                                      good + good), good + good), "malformed", "the latent form listed twice")
    add("varint-not-minimal", assemble(header([latent_form()], [b"\x81\x00a\x00"], good), good), "malformed",
        "the name length 1 written as 81 00 (not minimal)")
    add("varint-too-long", assemble(header([latent_form()], [descriptor("a", 0)], good,
                                           record_count=b"\x81\x80\x80\x80\x00"), good), "malformed",
        "the record count as a 5-byte varint")
    add("nan-mu", one(payload=f32(float("nan"), 0.0, 0.25, 0.5)), "malformed", "mu[0] is NaN (payload CRC valid)")
    add("sigma-zero", one(payload=f32(0.0, 0.0, 0.0, 0.5)), "malformed", "sigma[0] is 0 (payload CRC valid)")
    add("graft-value-infinite", one("g", f32(0.5, -1.0, 0.25, 0.5, np.inf), graft_form([1])), "malformed",
        "a graft value is +infinity (payload CRC valid)")
    add("graft-dims-repeated", one("g", f32(0.5, -1.0, 0.25, 0.5, 1.0, 2.0), graft_form([1, 1])), "malformed",
        "graft dimensions 1 and 1")
    add("graft-dim-range", one("g", f32(0.5, -1.0, 0.25, 0.5, 1.0), graft_form([2])), "malformed",
        "graft dimension 2 with latent_dim 2")
    # The metadata block (§5): JSON rules, types, names.
    block = canonical({"records": {"a": {"effort": 1}}})
    add("zstd-trailing-bytes", one(metadata=zstd(block) + b"\x00\x00", flags=1), "malformed",
        "two bytes after the metadata block's zstandard frame")
    half = len(block) // 2
    add("zstd-two-frames", one(metadata=zstd(block[:half]) + zstd(block[half:]), flags=1), "malformed",
        "the metadata split over two zstandard frames (a joining decoder would read valid metadata)")
    add("zstd-flag-without-metadata", one(flags=1), "malformed", "flag bit 0 set, but no metadata block")
    text = block.decode()
    add("number-overflow", one(metadata=text.replace('"effort":1', '"effort":1,"x":1e999').encode()),
        "malformed", "the number 1e999 (overflows binary64 to infinity)")
    add("integer-too-large", one(metadata=text.replace('"effort":1', '"effort":1,"x":9007199254740992').encode()),
        "malformed", "the integer 2^53, beyond I-JSON's exact range")
    add("duplicate-key", one(metadata=text.replace('"effort":1', '"effort":1,"effort":1').encode()),
        "malformed", "the key effort twice in one object")
    add("metadata-not-json", one(metadata=b"\xff{}"), "malformed", "a metadata block that is not UTF-8 JSON")
    add("metadata-array", one(metadata=b"[]"), "malformed", "a metadata block that is an array")
    add("created-by-number", with_meta({}, top={"created_by": 3}), "malformed", "created_by is the number 3")
    add("decoder-name-number", with_meta({}, top={"decoder_name": 3}), "malformed", "decoder_name is the number 3")
    add("metadata-unknown-name", one(metadata=canonical({"records": {"b": {}}})), "malformed",
        "metadata for a material 'b' the file does not hold")
    add("metadata-name-case", one("gold", metadata=canonical({"records": {"Gold": {}}})), "malformed",
        "metadata keyed 'Gold' for the record 'gold' (names match exactly)")
    add("metadata-record-array", with_meta([]), "malformed", "a record's metadata is an array")
    add("meta-relae-null", with_meta({"relae": {"mapped": None}}), "malformed", "relae.mapped is null")
    add("meta-relae-string", with_meta({"relae": {"mapped": "x"}}), "malformed", "relae.mapped is a string")
    add("meta-sha-type", with_meta({"source_sha256": 7}), "malformed", "source_sha256 is a number")
    add("meta-effort-string", with_meta({"effort": "1"}), "malformed", "effort is the string '1'")
    add("meta-effort-range", with_meta({"effort": 4}), "malformed", "effort is 4 (outside 0-3)")
    add("meta-rate-number", with_meta({"rate": 64}), "malformed", "rate is a number, not an object")
    add("meta-source-kind-number", with_meta({"source_kind": 1}), "malformed", "source_kind is a number")
    add("meta-edit-op", with_meta({"edit": {"op": 3}}), "malformed", "edit.op is a number")
    bomb = zstd(b"[" + b"{}," * (16 * 2**20 // 3 - 1) + b"{}]")
    add("header-amplification", one(metadata=bomb, flags=1), "malformed",
        f"a {len(bomb) + 100}-byte file whose metadata expands to 16 MiB of [{{}},{{}},...]: more JSON containers "
        "than the limit")
    add("metadata-too-deep", with_meta({"deep": json.loads("[" * 65 + "]" * 65)}), "malformed",
        "metadata JSON nested 68 levels deep")
    # Layered records (§4.4): a detail layer.
    detail = detail_frame([1], 63 * 90 * 90)
    lay_payload = good + detail
    lay = {"step": 0.1, "detail_length": len(detail)}
    add("layered-unknown-detail-form", one("l", lay_payload, layered_form(detail=2), **lay), "unsupported",
        "detail form code 2 (a transform or coefficient type this reader does not know)")
    add("layered-unknown-layer", one("l", lay_payload, layered_form(detail=0, layer_bits=2 | 16), **lay),
        "unsupported", "layer bit 4 set besides the detail layer's (bits 2 and 3, a packed and an entropy-coded "
        "basis layer, are known since 2.3 and 2.4)")
    add("layered-no-layer", one("l", good, layered_form(layer_bits=0)), "malformed",
        "a layered form with neither a basis nor a detail layer")
    add("detail-step-range", one("l", lay_payload, layered_form(detail=0), step=1000.0,
                                 detail_length=len(detail)), "malformed", "a detail step of 1000 (above 100)")
    add("detail-step-nan", one("l", lay_payload, layered_form(detail=0), step=float("nan"),
                               detail_length=len(detail)), "malformed", "a detail step that is NaN")
    short = detail_frame([1], 63 * 90 * 90 - 1)
    add("layered-content-size", one("l", good + short, layered_form(detail=0), step=0.1, detail_length=len(short)),
        "malformed", "a detail frame declaring one int16 fewer than 63*90*90 (payload CRC valid)")
    # The detail layer is exactly one frame, decompressed whole when the record is read (§4.4; issue 37): a reader
    # that checks only the frame header, or stops after the first frame, accepts these.
    frame_parts = detail_frame_blocks([1], 63 * 90 * 90)
    truncated = b"".join(frame_parts[:-2]) + _last_block(frame_parts[-2])  # content size declared, a block missing
    corrupt = bytearray(detail)
    corrupt[9] = (corrupt[9] & ~0b110) | (3 << 1)  # the first block's type: 3, reserved (corrupt)
    for label, data, why in [
        ("detail-trailing-bytes", detail + b"\x00junk", "5 bytes after the detail layer's zstandard frame"),
        ("detail-second-frame", detail + detail, "a second zstandard frame after the detail layer's"),
        ("detail-skippable-frame", detail + struct.pack("<II", 0x184D2A50, 4) + b"skip",
         "a skippable frame after the detail layer's zstandard frame"),
        ("detail-truncated-frame", truncated,
         "a detail frame whose blocks end before its declared content size (lengths and payload CRC valid)"),
        ("detail-corrupt-block", bytes(corrupt),
         "a detail frame whose first block has the reserved type 3 (its header valid, payload CRC valid)"),
    ]:
        add(label, one("l", good + data, layered_form(detail=0), step=0.1, detail_length=len(data)), "malformed",
            why)
    # The basis layer (§4.5): mu as float32, sigma as one byte each, the step (float16) and 3 coefficients.
    basis_payload = f32(0.5, -1.0) + bytes([160, 176]) + f16(0.25) + bytes([3, 253, 0])
    basis_sha = "cd" * 32

    def basis_file(form: bytes = layered_form(0, 1, basis=(0, 0)), payload: bytes = basis_payload, count: int = 3,
                   *, basis: str | None = basis_sha, flags: int = 2) -> bytes:
        return assemble(header([form], [descriptor("b", 0, count=count)], payload, basis=basis), payload,
                        flags=flags)

    add("basis-unknown-sigma", basis_file(layered_form(0, 4, basis=(0, 0))), "unsupported", "sigma code 4")
    add("basis-count-zero", basis_file(payload=basis_payload[:12], count=0), "malformed",
        "a basis layer of 0 coefficients")
    add("basis-count-payload", basis_file(count=4), "malformed",
        "count 4 but 3 coefficient bytes (the file one byte short of what the records need)")
    add("basis-step-nan", basis_file(payload=basis_payload[:10] + f16(np.nan) + basis_payload[12:]), "malformed",
        "the basis step is NaN (payload CRC valid)")
    add("basis-step-zero", basis_file(payload=basis_payload[:10] + f16(0) + basis_payload[12:]), "malformed",
        "the basis step is 0 (payload CRC valid)")
    add("basis-first-range", basis_file(layered_form(0, 1, basis=(4094, 0))), "malformed",
        "first 4094 with count 3 runs past the 4096 vectors a basis may hold")
    add("basis-project-range", basis_file(layered_form(0, 1, basis=(0, 4097))), "malformed",
        "a base projected on 4097 vectors (at most 4096)")
    add("basis-without-hash", basis_file(basis=None, flags=0), "malformed",
        "a basis layer in a file that names no shared basis (flag bit 1 clear)")
    add("basis-unused", assemble(header([latent_form()], [descriptor("a", 0)], good, basis=basis_sha), good, flags=2),
        "malformed", "a shared basis named (flag bit 1) in a file without basis layers")
    # Compact mu and the shared sigma byte: mu as a float16 step and int8 values, one sigma byte.
    compact_payload = f16(0.5) + bytes([2, 254]) + bytes([160]) + basis_payload[10:]
    add("compact-mu-unknown", basis_file(layered_form(5, 2, basis=(0, 0)), compact_payload), "unsupported",
        "mu code 5 (code 4, a coded mu, is known since 2.5)")
    add("compact-mu-step-nan", basis_file(layered_form(1, 2, basis=(0, 0)), f16(np.nan) + compact_payload[2:]),
        "malformed", "the compact mu step is NaN (payload CRC valid)")
    add("compact-sigma-length", basis_file(layered_form(1, 1, basis=(0, 0)), compact_payload), "malformed",
        "sigma as one byte per dimension, but the payload holds one shared byte (the file one byte short)")
    add("compact-mu-fixed-with-step", basis_file(layered_form(2, 2, basis=(0, 0)), compact_payload), "malformed",
        "mu on the fixed grid (no step) followed by a step's 2 bytes (two trailing bytes)")
    # Records without a latent (2.1, §4.6): mu and sigma "none" (code 3) only together, with a basis layer whose
    # base is not projected; the payload is the basis layer's bytes (then a detail layer's).
    only = f16(0.25) + bytes([3, 253, 0])
    add("basis-only-sigma-with-mu", basis_file(layered_form(0, 3, basis=(0, 0))), "malformed",
        "sigma 'none' (code 3) beside a mu stored in the latent dtype (valid since 2.2), but the payload lacks "
        "the mu's values (truncated)")

    add("basis-only-mu-with-sigma", basis_file(layered_form(3, 2, basis=(0, 0)), bytes([160]) + only), "malformed",
        "mu 'none' (code 3) beside a shared sigma byte")
    add("basis-only-no-basis", one("l", detail, layered_form(3, 3, detail=0), step=0.1, detail_length=len(detail)),
        "malformed", "mu and sigma 'none' with a detail layer but no basis layer")
    add("basis-only-projected", basis_file(layered_form(3, 3, basis=(0, 50)), only), "malformed",
        "mu and sigma 'none' with a base projected on 50 vectors (there is no decoder output to project)")
    add("basis-only-trailing-bytes", basis_file(layered_form(3, 3, basis=(0, 0)), only + f32(0.5, -1.0)),
        "malformed", "a record without a latent followed by the 8 bytes of a float32 mu (trailing bytes)")
    add("basis-only-unknown-sigma", basis_file(layered_form(3, 4, basis=(0, 0)), only), "unsupported",
        "mu 'none' with sigma code 4: an unknown code is unsupported before the pairing is checked")
    # Packed basis layers (2.3, §4.7): form bit 2 and a top width; the step code, then the fields. T = 9 from
    # vector 0: widths 9, 8, 7 (24 bits: 3 bytes); values 3, -3, 0 least significant bit first.
    packed = bytes([128, 3, 250, 1])
    packed_form = layered_form(3, 3, basis=(0, 0), top=9)
    add("packed-padding-bits", basis_file(layered_form(3, 3, basis=(0, 0), top=8), packed[:1] + bytes([3, 125, 128])),
        "malformed", "top width 8 (widths 8, 7, 6: 21 bits), but an unused bit of the last byte is set")
    add("packed-too-many", basis_file(layered_form(3, 3, basis=(0, 0), top=1), packed[:1] + bytes([1]), count=2),
        "malformed", "top width 1 holds one coefficient (the second's field would be 0 bits wide), count 2")
    add("packed-top-zero", basis_file(layered_form(3, 3, basis=(0, 0), top=0), packed), "malformed",
        "a packed basis layer of top width 0 (1 to 24)")
    add("packed-top-range", basis_file(layered_form(3, 3, basis=(0, 0), top=25), packed), "malformed",
        "a packed basis layer of top width 25 (1 to 24)")
    add("packed-without-basis", one("l", detail, layered_form(0, 1, detail=0, layer_bits=6), step=0.1,
                                    detail_length=len(detail)),
        "malformed", "layer bit 2 (a packed basis layer) without bit 0 (a basis layer)")
    add("packed-short", basis_file(packed_form, packed[:3]), "malformed",
        "widths 9, 8, 7 take 3 bytes after the step code, the file holds 2")
    # Entropy-coded basis layers (2.4, §4.8): form bit 3 and a prior (A, d) = (64, 32); the descriptor's count,
    # then the layer's length; the step code 128, then the coder's bytes. q = 3, -3, 0 from vector 0: prior codes
    # 0, -16, -26, coded as bf 1b a8.
    coded = bytes([128, 0xBF, 0x1B, 0xA8])
    coded_form = bytes([2, 3, 3, 1 | 8]) + varint(0) + varint(0) + bytes([64, 32])

    def coded_file(form: bytes, payload: bytes, count: int = 3, length: int | None = None) -> bytes:
        entry = descriptor("b", 0, count=count) + varint(len(payload) if length is None else length)
        return assemble(header([form], [entry], payload, basis=basis_sha), payload, flags=2)

    add("coded-trailing-zero", coded_file(coded_form, coded + b"\x00"), "malformed",
        "the coder's bytes followed by a 0 byte: they decode to the same integers, but are not the shortest coding")
    add("coded-escape-prefix", coded_file(coded_form, bytes([128]) + b"\xff" * 8, count=1), "malformed",
        "coder bytes all ones: an Exp-Golomb escape prefix longer than 20 bits")
    add("coded-and-packed", coded_file(bytes([2, 3, 3, 1 | 4 | 8]) + varint(0) + varint(0) + bytes([9, 64, 32]),
                                       coded), "malformed", "layer bits 2 and 3 together (packed and entropy-coded)")
    add("coded-without-basis", one("l", detail, layered_form(0, 1, detail=0, layer_bits=2 | 8), step=0.1,
                                   detail_length=len(detail)),
        "malformed", "layer bit 3 (an entropy-coded basis layer) without bit 0 (a basis layer)")
    add("coded-length-zero", coded_file(coded_form, b"", length=0), "malformed",
        "a coded basis layer of length 0 (it holds at least the step code)")
    # A coded mu (2.5, §4.9): mu code 4, sigma 3, layer bits 0 and 3, the prior, then the grid exponent g.
    coded_mu_form = bytes([2, 4, 3, 1 | 8]) + varint(0) + varint(0) + bytes([64, 32])
    add("coded-mu-step-zero", coded_file(coded_mu_form + bytes([0]), coded), "malformed",
        "a coded mu on the grid 2^-0 (g is 1 to 5)")
    add("coded-mu-step-six", coded_file(coded_mu_form + bytes([6]), coded), "malformed",
        "a coded mu on the grid 2^-6 (g is 1 to 5: its prior code 96 is past the tables' 80)")
    add("coded-mu-packed-layer", basis_file(layered_form(4, 3, basis=(0, 0), top=9), packed), "malformed",
        "mu code 4 (coded in an entropy-coded layer's stream) with a packed basis layer (layer bit 3 clear)")
    add("coded-mu-short", coded_file(coded_mu_form + bytes([4]), coded), "malformed",
        "a coded mu whose stream holds the 3 coefficients' integers only: the 8 mu integers read first, and the "
        "bytes are not the shortest coding of what they decode to")
    # Form variants (2.7, §3.2): kind 3, the base form's index, the changes byte, the changed fields.

    def variant_file(forms: list[bytes]) -> bytes:
        entries = [descriptor(n, i, count=3) + varint(len(coded)) for i, n in zip(range(2), "bc", strict=True)]
        return assemble(header(forms, entries, coded + coded, basis=basis_sha), coded + coded, flags=2, minor=7)

    add("variant-base-later", variant_file([coded_form, bytes([3, 1, 8, 80, 32])]), "malformed",
        "form 1 a variant of form 1 (a variant's base is an earlier form)")
    add("variant-base-latent", assemble(header([latent_form(), bytes([3, 0, 8, 80, 32])],
                                               [descriptor("a", 0), descriptor("c", 1, count=3) + varint(4)],
                                               good + coded, basis=basis_sha), good + coded, flags=2, minor=7),
        "malformed", "a variant of a latent form (a variant's base is a layered form)")
    add("variant-no-change", variant_file([coded_form, bytes([3, 0, 0])]), "malformed",
        "a variant whose changes byte is 0 (it would be its base again)")
    add("variant-reserved-bit", variant_file([coded_form, bytes([3, 0, 0x40])]), "unsupported",
        "a variant whose changes byte sets bit 6 (reserved)")
    add("variant-absent-field", variant_file([coded_form, bytes([3, 0, 0x10, 2])]), "malformed",
        "a variant that changes the mu step of a form without a coded mu")
    add("variant-same-as-base", variant_file([coded_form, bytes([3, 0, 8, 64, 32])]), "malformed",
        "a variant that sets its base's prior to the value it has (a variant names only the fields that differ)")
    add("variant-twice-through-variant", variant_file([coded_form, bytes([3, 0, 8, 80, 32]), bytes([3, 1, 8, 64, 32])]),
        "malformed", "form 2, a variant of form 1 that sets the prior back to form 0's: form 0 twice")
    add("variant-two-rules", variant_file([coded_form, bytes([3, 0, 0x50, 2])]), "unsupported",
        "a variant whose changes byte sets reserved bit 6 and bit 4 (a mu step its base lacks): the reserved bit first")
    add("variant-base-graft", assemble(header([graft_form([1]), bytes([3, 0, 8, 80, 32])],
                                              [descriptor("a", 0), descriptor("c", 1, count=3) + varint(4)],
                                              good + coded, basis=basis_sha), good + coded, flags=2, minor=7),
        "malformed", "a variant of a graft form (a variant's base is a layered form)")
    add("variant-detail-unknown", assemble(header([layered_form(0, 1, detail=0), bytes([3, 0, 0x20, 7])],
                                                  [descriptor("a", 0), descriptor("c", 1)], good, basis=None),
                                           good, minor=7),
        "unsupported", "a variant that sets its base's detail form to 7, a code this reader does not know")
    add("variant-first-range", variant_file([coded_form, bytes([3, 0, 1]) + varint(4096)]), "malformed",
        "a variant whose first is 4096 (0 to 4095, checked as in a form written in full)")
    for label, name, why in [
        ("name-parent", "../UP", "a name holding '/' and '..'"),
        ("name-absolute", "/tmp/ESCAPED", "an absolute path as a name"),
        ("name-dot", ".", "the name '.'"),
        ("name-dotdot", "..", "the name '..'"),
        ("name-hidden", ".gold", "a name starting with '.'"),
        ("name-backslash", "a\\b", "a name holding a backslash"),
        ("name-c0-control", "a\nb", "a name holding U+000A"),
        ("name-c1-control", "a\u0085b", "a name holding U+0085 (C1 control)"),
        ("name-not-nfc", "cafe\u0301", "'café' in NFD, not NFC"),
        ("name-empty", "", "the empty name"),
        ("name-device", "NUL", "a Windows device name"),
        ("name-device-space", "CON .txt", "a Windows device name before its first '.', white space at its end "
                                          "ignored (§4.3)"),
        ("name-too-long", "x" * 241, "a name of 241 bytes (at most 240, §4.3)"),
        ("name-bom", "\ufeffgold", "a name that starts with U+FEFF (a byte-order mark)"),
        ("name-device-superscript", "COM\u00b9", "the Windows device name COM¹ (superscript one)"),
    ]:
        add(label, one(name), "malformed", why)
    add("name-not-utf8", one(b"a\xffb"), "malformed", "a name whose bytes are not UTF-8")
    add("name-surrogate", one(b"a\xed\xa0\x80"), "malformed", "a name holding an encoded surrogate (CESU, not UTF-8)")
    add("name-case-twins", assemble(header([latent_form()], [descriptor("Gold", 0), descriptor("gold", 0)],
                                           good + good), good + good), "malformed",
        "names 'Gold' and 'gold' (equal after case folding)")
    add("name-file-twins", assemble(header([latent_form()], [descriptor("a\u200bb", 0), descriptor("A[U+200B]B", 0)],
                                           good + good), good + good), "malformed",
        "names 'a' U+200B 'b' and 'A[U+200B]B' (one file name once format characters are written [U+XXXX])")
    add("name-duplicate", assemble(header([latent_form()], [descriptor("a", 0), descriptor("a", 0)], good + good),
                                   good + good), "malformed", "the name 'a' twice")
    return out


def detail_frame_blocks(head: list[int], total: int) -> list[bytes]:
    """:func:`detail_frame` in parts: the frame header, then each block (its 3-byte header and body)."""
    frame = detail_frame(head, total)
    parts, at = [frame[:9]], 9
    while at < len(frame):
        header = int.from_bytes(frame[at : at + 3], "little")
        size = 1 if (header >> 1) & 3 == 1 else header >> 3  # an RLE block's body is one byte
        parts.append(frame[at : at + 3 + size])
        at += 3 + size
    return parts


def _last_block(block: bytes) -> bytes:
    """A block with its 'last block' bit set."""
    return bytes([block[0] | 1]) + block[1:]


def detail_frame(head: list[int], total: int) -> bytes:
    """A zstandard frame written by hand (independent of the zstandard library's version): int16 ``head``
    as a raw block, then zeros as RLE blocks, ``total`` int16 values in all; the frame declares its content size."""
    raw = np.array(head, dtype="<i2").tobytes()
    content = total * 2
    out = bytearray(struct.pack("<I", 0xFD2FB528))
    out += bytes([0b1010_0000])  # Frame_Content_Size 4 bytes, single segment, no checksum, no dictionary
    out += struct.pack("<I", content)
    blocks = [(0, len(raw), raw)]  # (type, size, body): type 0 raw, 1 RLE (one byte repeated size times)
    left = content - len(raw)
    while left:
        size = min(left, 128 * 1024)
        blocks.append((1, size, b"\x00"))
        left -= size
    for i, (kind, size, body) in enumerate(blocks):
        last = int(i == len(blocks) - 1)
        out += (last | kind << 1 | size << 3).to_bytes(3, "little") + body
    return bytes(out)


def layered_record(name: str, mu: np.ndarray, sigma: np.ndarray) -> LatentRecord:
    """A layered record (§4.4) whose detail layer has three non-zero DCT coefficients (step 0.125)."""
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.detail import N_DETAIL_VALUES, DetailLayer

    layer = DetailLayer(0.125, "int16", detail_frame([8, -4, 2], N_DETAIL_VALUES))
    return LayeredRecord(name, mu, sigma, {"effort": 1, "rate": {"payload_bytes": 64 + len(layer.data),
                                                                 "candidates_tried": 1}}, detail=layer)


def basis_record(name: str, mu: np.ndarray, sigma: np.ndarray, sha256: str, *, detail: bool = False,
                 first: int = 0, compact_base: bool = False, fixed_grid: bool = False, project: int = 0
                 ) -> LatentRecord:
    """A layered record (§4.4) with compact sigma and 5 coefficients on a shared basis from vector ``first``
    (and a detail layer); with ``compact_base``, compact mu and the shared sigma byte instead (since 1.4),
    with ``fixed_grid`` too, mu on the fixed grid (since 1.5); with ``project``, the base projected on that
    many basis vectors (since 1.6)."""
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.detail import N_DETAIL_VALUES, DetailLayer

    layer = DetailLayer(0.125, "int16", detail_frame([8, -4, 2], N_DETAIL_VALUES)) if detail else None
    basis = BasisLayer(sha256, 0.5, np.array([12, -7, 3, 0, -1], dtype=np.int8), first, project)
    storage = {"compact_mu": True, "shared_sigma": True, "fixed_mu_grid": fixed_grid} if compact_base else {
        "compact_sigma": True}
    return LayeredRecord(name, mu, sigma, {"effort": 1}, detail=layer, basis=basis, **storage)


def basis_only_record(name: str, sha256: str, *, detail: bool = False) -> LatentRecord:
    """A record without a latent (§4.6, since 2.1): 5 coefficients from vector 0 (and a detail layer)."""
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.detail import N_DETAIL_VALUES, DetailLayer

    layer = DetailLayer(0.125, "int16", detail_frame([8, -4, 2], N_DETAIL_VALUES)) if detail else None
    basis = BasisLayer(sha256, 0.5, np.array([24, -7, 3, 0, -1], dtype=np.int8))
    return LayeredRecord.without_latent(name, 8, basis, detail=layer)


def no_sigma_records() -> tuple[list, DecoderReference, str, bool | None]:
    """Records that store a latent without sigma (since 2.2): the base alone, and one with a basis layer, beside a
    plain latent record (written as 2.2: the preamble states the lowest version that holds the file)."""
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer

    rng = np.random.default_rng(2028)  # its own draws: the other vectors keep their values
    mu = lambda: (np.round(rng.normal(size=8) * 8) / 8).astype(np.float32)  # noqa: E731 - exact in float16
    sigma = (2.0 ** -rng.integers(1, 6, size=8)).astype(np.float32)
    basis = BasisLayer("cd" * 32, 0.5, np.array([12, -7, 3], dtype=np.int8))
    return ([LayeredRecord.code_only(LatentRecord("gold.no-sigma", mu(), sigma)),
             LayeredRecord("gold.no-sigma-basis", mu(), sigma, {"effort": 1}, basis=basis, store_sigma=False),
             LatentRecord("gold", mu(), sigma)], TEST_DECODER, "float32", False)


def coded_records() -> tuple[list, DecoderReference, str, bool | None]:
    """Records whose basis layer is entropy-coded (since 2.4): one without a latent, one on a compact base from
    vector 8, one on a float32 base, and one whose integers are all 0 (no coder bytes)."""
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.packed import packed_step

    rng = np.random.default_rng(2030)  # its own draws: the other vectors keep their values
    mu = lambda: (np.round(rng.normal(size=8) * 8) / 8).astype(np.float32)  # noqa: E731 - exact on the grid
    sigma = (2.0 ** -rng.integers(1, 6, size=8)).astype(np.float32)
    sha = "cd" * 32
    only = BasisLayer(sha, packed_step(128), np.array([200, -90, 41, -7, 0, 3, -1, 40000]), 0, 0, prior=(160, 40))
    after = BasisLayer(sha, packed_step(100), np.array([25, -17, 0, 9, -2, 1]), 8, 0, prior=(128, 32))
    zeros = BasisLayer(sha, packed_step(90), np.zeros(4, dtype=np.int64), 8, 0, prior=(128, 32))
    return ([LayeredRecord.without_latent("gold.coded-basis-only", 8, only),
             LayeredRecord("gold.coded-compact", mu(), sigma, {"effort": 1}, basis=after, compact_mu=True,
                           fixed_mu_grid=True, store_sigma=False),
             LayeredRecord("gold.coded", mu(), sigma, {"effort": 1}, basis=after, compact_sigma=True),
             LayeredRecord("gold.coded-zeros", mu(), sigma, basis=zeros, store_sigma=False)],
            TEST_DECODER, "float32", False)


def coded_mu_records() -> tuple[list, DecoderReference, str, bool | None]:
    """Records whose μ is entropy-coded in their coded basis layer (since 2.5): on the grids 2^−4 and 2^−1, one
    with a shared σ byte, one with a μ of zeros and a coefficient of magnitude 20 (an escape)."""
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.packed import packed_step

    rng = np.random.default_rng(2031)  # its own draws: the other vectors keep their values
    mu = lambda: (np.round(rng.normal(size=8) * 16) / 16).astype(np.float32)  # noqa: E731 - on the grid 2^-4
    sigma = (2.0 ** -rng.integers(1, 6, size=8)).astype(np.float32)
    sha = "cd" * 32
    after = BasisLayer(sha, packed_step(100), np.array([25, -17, 0, 9, -2, 1]), 8, 0, prior=(128, 32))
    escape = BasisLayer(sha, packed_step(120), np.array([20, 0, -3]), 8, 0, prior=(156, 28))
    return ([LayeredRecord("gold.coded-mu", mu(), sigma, {"effort": 1}, basis=after, coded_mu=4, store_sigma=False),
             LayeredRecord("gold.coded-mu-half", mu(), sigma, basis=after, coded_mu=1, shared_sigma=True),
             LayeredRecord("gold.coded-mu-zero", np.zeros(8, np.float32), sigma, basis=escape, coded_mu=4,
                           store_sigma=False)],
            TEST_DECODER, "float32", False)


def packed_records() -> tuple[list, DecoderReference, str, bool | None]:
    """Records whose basis layer is packed (since 2.3): one without a latent, one on a compact base from vector 8,
    and one on a float32 base, beside an int8 layer (written as 2.3)."""
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.packed import packed_step

    rng = np.random.default_rng(2029)  # its own draws: the other vectors keep their values
    mu = lambda: (np.round(rng.normal(size=8) * 8) / 8).astype(np.float32)  # noqa: E731 - exact on the grid
    sigma = (2.0 ** -rng.integers(1, 6, size=8)).astype(np.float32)
    sha = "cd" * 32
    only = BasisLayer(sha, packed_step(128), np.array([200, -90, 41, -7, 0, 3, -1]), 0, 0, 9)
    after = BasisLayer(sha, packed_step(100), np.array([25, -17, 0, 9, -2, 1]), 8, 0, 9)
    return ([LayeredRecord.without_latent("gold.packed-basis-only", 8, only),
             LayeredRecord("gold.packed-compact", mu(), sigma, {"effort": 1}, basis=after, compact_mu=True,
                           fixed_mu_grid=True, store_sigma=False),
             LayeredRecord("gold.packed", mu(), sigma, {"effort": 1}, basis=after, compact_sigma=True),
             LayeredRecord("gold.int8", mu(), sigma, {"effort": 1},
                           basis=BasisLayer(sha, 0.5, np.array([12, -7, 3], dtype=np.int8), 8), store_sigma=False)],
            TEST_DECODER, "float32", False)


def short_reference_records() -> tuple[list, DecoderReference, str, bool | None]:
    """Records of a file with short references (since 2.6): the shipped decoder and its basis named by the first
    8 bytes of their SHA-256, a plain latent record beside one with a basis layer."""
    rng = np.random.default_rng(2032)  # its own draws: the other vectors keep their values
    mu = lambda: (np.round(rng.normal(size=8) * 8) / 8).astype(np.float32)  # noqa: E731 - exact in float16
    sigma = lambda: (2.0 ** -rng.integers(1, 6, size=8)).astype(np.float32)  # noqa: E731
    return ([LatentRecord("reference.short", mu(), sigma()),
             basis_record("reference.short-basis", mu(), sigma(), SHIPPED_BASIS[:16], first=8)],
            SHIPPED_DECODER.shortened(), "float16", False)


def form_variant_records() -> tuple[list, DecoderReference, str, bool | None]:
    """Records of a file whose form table holds variants (since 2.7): coded-μ records that differ in their grid,
    their prior, their first vector and projection, one of them a variant of a variant, beside a form of
    another layout (μ in float32), written in full."""
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.packed import packed_step

    rng = np.random.default_rng(2033)  # its own draws: the other vectors keep their values
    mu = lambda: (np.round(rng.normal(size=8) * 4) / 4).astype(np.float32)  # noqa: E731 - on the grids 2^-2, 2^-3
    sigma = (2.0 ** -rng.integers(1, 6, size=8)).astype(np.float32)
    sha = "cd" * 8  # a short reference (2.6)

    def layer(first: int, project: int, prior: tuple[int, int]) -> BasisLayer:
        return BasisLayer(sha, packed_step(100), np.array([25, -17, 0, 9, -2, 1]), first, project, prior=prior)

    return ([LayeredRecord("gold.variant-base", mu(), sigma, basis=layer(8, 0, (156, 28)), coded_mu=3,
                           store_sigma=False),
             LayeredRecord("gold.variant-grid", mu(), sigma, basis=layer(8, 0, (156, 28)), coded_mu=2,
                           store_sigma=False),
             LayeredRecord("gold.variant-prior", mu(), sigma, basis=layer(8, 0, (188, 28)), coded_mu=3,
                           store_sigma=False),
             LayeredRecord("gold.variant-of-variant", mu(), sigma, basis=layer(0, 50, (156, 28)), coded_mu=2,
                           store_sigma=False),
             LayeredRecord("gold.full-form", mu(), sigma, basis=layer(8, 0, (156, 28)), store_sigma=False)],
            TEST_DECODER.shortened(), "float32", False)


def valid_records() -> dict[str, tuple[list, DecoderReference, str, bool | None]]:
    """name -> (records, decoder, latent dtype, compress header)."""
    rng = np.random.default_rng(2026)
    halves = lambda size: (np.round(rng.normal(size=size) * 8) / 8).astype(np.float32)  # noqa: E731 - exact in f16
    sigma = lambda size: (2.0 ** -rng.integers(1, 6, size=size)).astype(np.float32)  # noqa: E731
    # Records added since 1.5 draw from their own generator, so the earlier vectors keep their values.
    later = np.random.default_rng(2027)
    halves15 = lambda size: (np.round(later.normal(size=size) * 8) / 8).astype(np.float32)  # noqa: E731
    # ... and those added since 1.6 from theirs.
    latest = np.random.default_rng(2028)
    halves16 = lambda size: (np.round(latest.normal(size=size) * 8) / 8).astype(np.float32)  # noqa: E731
    lib = [LatentRecord(f"material-{i}", halves(8), sigma(8),
                        {"source_sha256": f"{i:x}" * 64, "relae": {"mapped": 0.03125 * (i + 1), "linear": 0.25}})
           for i in range(3)]
    return {
        "one-material": ([LatentRecord("gold", halves(8), sigma(8))], TEST_DECODER, "float32", False),
        # §4.3: format characters (category Cf) are allowed in names; the rules are a complete list (issue 37).
        "name-format-characters": ([LatentRecord("gold\u200bleaf\u202e", np.full(8, 0.5, dtype=np.float32),
                                                 np.full(8, 0.25, dtype=np.float32))], TEST_DECODER, "float32", False),
        "library": (lib, TEST_DECODER, "float32", False),
        "float16": ([LatentRecord(r.name, r.mu, r.sigma) for r in lib], TEST_DECODER, "float16", False),
        "graft": ([GraftRecord("gold.graft", halves(8), sigma(8), (3, 4), [0.5, -1.0],
                               {"edit": {"op": "graft", "source": "gold"}})], TEST_DECODER, "float32", False),
        "compressed-header": (lib, TEST_DECODER, "float32", True),
        "unicode-names": ([LatentRecord("café", halves(8), sigma(8)), LatentRecord("Ölfarbe №2 ☀", halves(8),
                                                                                  sigma(8))],
                          TEST_DECODER, "float32", False),
        "reference-decode": ([LatentRecord("reference", halves(8), sigma(8)),
                              GraftRecord("reference.graft", halves(8), sigma(8), (3, 4), [1.5, -0.5])],
                             SHIPPED_DECODER, "float32", False),
        "reference-decode-layers": ([basis_record("reference.basis", halves(8), sigma(8), SHIPPED_BASIS),
                                     basis_record("reference.basis-detail", halves(8), sigma(8), SHIPPED_BASIS,
                                                  detail=True),
                                     basis_record("reference.basis-first", halves(8), sigma(8), SHIPPED_BASIS,
                                                  first=8),
                                     basis_record("reference.basis-compact", halves(8), sigma(8), SHIPPED_BASIS,
                                                  first=8, compact_base=True),
                                     basis_record("reference.basis-fixed-grid", halves15(8), np.full(8, 0.125),
                                                  SHIPPED_BASIS, first=8, compact_base=True, fixed_grid=True),
                                     basis_record("reference.basis-projected", halves16(8), np.full(8, 0.125),
                                                  SHIPPED_BASIS, first=8, compact_base=True, fixed_grid=True,
                                                  project=50),
                                     basis_only_record("reference.basis-only", SHIPPED_BASIS),
                                     basis_only_record("reference.basis-only-detail", SHIPPED_BASIS, detail=True)],
                                    SHIPPED_DECODER, "float16", False),
        # Records without a latent (since 2.1) beside one with: the payload is the basis layer's bytes.
        "basis-only": ([basis_only_record("gold.basis-only", "cd" * 32),
                        basis_only_record("gold.basis-only-detail", "cd" * 32, detail=True),
                        basis_record("gold.basis", halves16(8), sigma(8), "cd" * 32)],
                       TEST_DECODER, "float32", False),
        "layered": ([layered_record("gold.layered", halves(8), sigma(8)),
                     LatentRecord("gold", halves(8), sigma(8), {"effort": 0, "source_kind": "rgl-measured"}),
                     basis_record("gold.basis", halves(8), sigma(8), "cd" * 32, detail=True),
                     basis_record("gold.basis-first", halves(8), sigma(8), "cd" * 32, first=8),
                     basis_record("gold.basis-compact", halves(8), sigma(8), "cd" * 32, first=8, compact_base=True),
                     basis_record("gold.basis-fixed-grid", halves15(8), np.full(8, 0.125), "cd" * 32, first=8,
                                  compact_base=True, fixed_grid=True),
                     basis_record("gold.basis-projected", halves16(8), np.full(8, 0.125), "cd" * 32, first=8,
                                  compact_base=True, fixed_grid=True, project=50)],
                    TEST_DECODER, "float32", False),
        # An edit whose decode the highlight guard changes (§6 step 6, issue 50): z1 at +3σ from the zero code.
        "reference-decode-edits": ([LatentRecord("reference.z1+3", np.array([3, 0, 0, 0, 0, 0, 0, 0], np.float32),
                                                 np.ones(8, np.float32),
                                                 {"edit": {"op": "traverse", "source": "reference", "parameter": 1,
                                                           "value": 3.0, "unit": "sigma"}})],
                                    SHIPPED_DECODER, "float32", False),
        "no-sigma": no_sigma_records(),
        "packed-basis": packed_records(),
        "coded-basis": coded_records(),
        "coded-mu": coded_mu_records(),
        "reference-decode-short": short_reference_records(),
        "form-variants": form_variant_records(),
    }


def describe(record: LatentRecord | GraftRecord) -> dict[str, Any]:
    latent = getattr(record, "has_latent", True)  # a record without a latent (§4.6): mu and sigma null
    item: dict[str, Any] = {"name": record.name, "kind": record.kind, "mu": record.mu.tolist() if latent else None,
                            "sigma": record.sigma.tolist() if latent else None, "meta": dict(record.meta)}
    if isinstance(record, GraftRecord):
        item["graft_dims"] = list(record.graft_dims)
        item["graft_values"] = record.graft_values.tolist()
    if record.kind == "layered":
        from brdfcodec.format.layered_record import layers_entry

        item["layers"] = layers_entry(record)  # type: ignore[arg-type]
    return item


def reference_values(records: list) -> dict[str, list[float]]:
    """Decoded values at REFERENCE_ENTRIES for each record, with the shipped model (masked as -1)."""
    from brdfcodec.codec import BrdfDecoder

    decoder = BrdfDecoder(SHIPPED_FOLDER)
    assert decoder.reference == SHIPPED_DECODER, "the vectors' model changed: regenerate and review the vectors"
    values = {}
    for record in records:
        table = decoder.decode(record)
        values[record.name] = [float(table[tuple(e)]) for e in REFERENCE_ENTRIES]
    return values


def guarded_entries(records: list, count: int = 6) -> list[list[int]]:
    """REFERENCE_ENTRIES and, for the first record, the ``count`` entries above the horizon (at kept φd bins) where
    the highlight guard (§6 step 6) raises the table most, with the shipped model."""
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.conventions import KEPT_PHI_D_SLICES
    from brdfcodec.representation import table_from_mapped
    from brdfcodec.representation.highlight_guard import guard_highlight
    from brdfcodec.representation.mask import horizon_mask

    decoder = BrdfDecoder(SHIPPED_FOLDER)
    mapped = decoder.decode_mapped(records[0].mu[None])[0]
    raised = (table_from_mapped(guard_highlight(mapped), phi_d_bins=KEPT_PHI_D_SLICES)
              - table_from_mapped(mapped, phi_d_bins=KEPT_PHI_D_SLICES))
    raised = np.where(horizon_mask()[..., list(KEPT_PHI_D_SLICES)], raised, 0)
    order = np.argsort(raised, axis=None)[::-1][:count]
    chosen = [[int(c), int(h), int(d), int(KEPT_PHI_D_SLICES[s])] for c, h, d, s in zip(*np.unravel_index(
        order, raised.shape), strict=True) if raised[c, h, d, s] > 0]
    assert len(chosen) == count, "the edit vector's record no longer has a highlight the guard changes"
    return [*REFERENCE_ENTRIES, *chosen]


def reference_values_at(records: list, entries: list[list[int]]) -> dict[str, list[float]]:
    """Decoded values at ``entries`` for each record, with the shipped model (masked as -1)."""
    from brdfcodec.codec import BrdfDecoder

    decoder = BrdfDecoder(SHIPPED_FOLDER)
    tables = {record.name: decoder.decode(record) for record in records}
    return {name: [float(table[tuple(e)]) for e in entries] for name, table in tables.items()}


def generate(folder: Path, *, with_reference: bool = True) -> dict[str, Any]:
    """Write every vector and ``manifest.json`` into ``folder``; return the manifest."""
    (folder / "valid").mkdir(parents=True, exist_ok=True)
    (folder / "invalid").mkdir(parents=True, exist_ok=True)
    manifest: dict[str, Any] = {
        "format_version": "2.7",
        "error_classes": {
            "malformed": "BvaeFormatError",
            "checksum": "BvaeChecksumError",
            "unsupported": "UnsupportedVersionError",
            "latent-dimension": "LatentDimensionError",
        },
        "valid": [],
        "invalid": [],
        "decode": {},
    }
    for name, (records, decoder, dtype, compress) in valid_records().items():
        path = folder / "valid" / f"{name}.bvae"
        path.write_bytes(encode_bvae(records, decoder, latent_dtype=dtype, compress_header=compress))
        bases = sorted({r.basis.sha256 for r in records if getattr(r, "basis", None) is not None})
        data = path.read_bytes()
        manifest["valid"].append({
            "file": f"valid/{name}.bvae", "format_version": f"{data[8]}.{data[10]}",  # the preamble's (§2)
            "decoder_sha256": decoder.sha256, "basis_sha256": (bases or [None])[0],
            "latent_dtype": dtype, "header_compressed": bool(compress) and any(r.meta for r in records),
            "records": [describe(r) for r in records],
        })
        if name == "reference-decode" and with_reference:
            manifest["decode"] = {
                "file": f"valid/{name}.bvae", "entries": REFERENCE_ENTRIES, "rtol": DECODE_RTOL, "atol": DECODE_ATOL,
                "masked": "unmeasured", "units": "stored MERL units (float32)",
                "values": reference_values(records),
            }
        if name == "reference-decode-edits" and with_reference:
            entries = guarded_entries(records)
            manifest["decode_edits"] = {
                "file": f"valid/{name}.bvae", "entries": entries, "rtol": DECODE_RTOL, "atol": DECODE_ATOL,
                "masked": "unmeasured", "units": "stored MERL units (float32)",
                "values": reference_values_at(records, entries),
            }
        if name == "reference-decode-short" and with_reference:
            manifest["decode_short"] = {
                "file": f"valid/{name}.bvae", "entries": REFERENCE_ENTRIES, "rtol": DECODE_RTOL, "atol": DECODE_ATOL,
                "masked": "unmeasured", "units": "stored MERL units (float32)", "basis_sha256": SHIPPED_BASIS[:16],
                "values": reference_values(records),
            }
        if name == "reference-decode-layers" and with_reference:
            manifest["decode_layers"] = {
                "file": f"valid/{name}.bvae", "entries": REFERENCE_ENTRIES, "rtol": DECODE_RTOL, "atol": DECODE_ATOL,
                "masked": "unmeasured", "units": "stored MERL units (float32)", "basis_sha256": SHIPPED_BASIS,
                "values": reference_values(records),
            }
    # Written by hand: a record's metadata is {} (valid: it says nothing; a writer leaves it out, §5.3).
    empty = f32(0.5, -1.0, 0.25, 0.5)
    (folder / "valid" / "metadata-empty.bvae").write_bytes(assemble(header(
        [latent_form()], [descriptor("a", 0)], empty, metadata=canonical({"records": {"a": {}}})), empty))
    manifest["valid"].append({
        "file": "valid/metadata-empty.bvae", "format_version": "2.1", "decoder_sha256": TEST_DECODER.sha256, "basis_sha256": None,
        "latent_dtype": "float32", "header_compressed": False,
        "records": [{"name": "a", "kind": "latent", "mu": [0.5, -1.0], "sigma": [0.25, 0.5], "meta": {}}],
    })
    # Written by hand: a file of version 2.0 (a 2.1 reader reads every 2.0 file as before).
    (folder / "valid" / "version-2.0.bvae").write_bytes(assemble(header(
        [latent_form()], [descriptor("a", 0)], empty), empty, minor=0))
    manifest["valid"].append({
        "file": "valid/version-2.0.bvae", "format_version": "2.0", "decoder_sha256": TEST_DECODER.sha256,
        "basis_sha256": None, "latent_dtype": "float32", "header_compressed": False,
        "records": [{"name": "a", "kind": "latent", "mu": [0.5, -1.0], "sigma": [0.25, 0.5], "meta": {}}],
    })
    for name, (data, error, why) in invalid_vectors().items():
        (folder / "invalid" / f"{name}.bvae").write_bytes(data)
        manifest["invalid"].append({"file": f"invalid/{name}.bvae", "error": error, "why": why})
    # Valid at the byte level, refused when opened for decoding (§6): latent_dim 4 with the shipped 8-D decoder.
    wrong = encode_bvae([LatentRecord("small", [0.0] * 4, [1.0] * 4)], SHIPPED_DECODER, compress_header=False)
    (folder / "invalid" / "latent-size-mismatch.bvae").write_bytes(wrong)
    manifest["invalid"].append({"file": "invalid/latent-size-mismatch.bvae", "error": "latent-dimension",
                                "when": "decode", "why": "latent_dim 4, but the named (shipped) decoder has 8"})
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    return manifest


if __name__ == "__main__":
    generate(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
