"""Generate the conformance vectors of ``spec/bvae-format.md`` (§9) and their ``manifest.json``.

Run from the repository root: ``python spec/vectors/make_vectors.py`` (writes
into ``spec/vectors/``), or ``python spec/vectors/make_vectors.py OUT_DIR``.

Valid files come from the reference writer; invalid files are built byte by
byte here (JSON text, zstandard frame, CRC-32 and preamble written by hand),
so that each breaks exactly one rule, or exactly the two rules whose
precedence §7 settles. The expected decoder values are measured with the
shipped model and stored with the tolerance §9 states.
"""

from __future__ import annotations

import json
import struct
import sys
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.bvae_format import DecoderReference, GraftRecord, LatentRecord, encode_bvae

HERE = Path(__file__).resolve().parent
MAGIC = b"\x89BVAE\r\n\x1a"
#: The shipped default model's decoder (``brdfcodec/data/models/default``).
SHIPPED_DECODER = DecoderReference(
    "e1e3ed1e24dc5a8746abbfb9194725e1a9d02808c2e81125c64f3d9e37b39491", "bvae-nbrdf-proxy-small-v1"
)
TEST_DECODER = DecoderReference("ab" * 32, "conformance-test-decoder")
#: SHA-256 of the shipped default model's first shared basis (a previous basis since 1.6, kept for decoding).
SHIPPED_BASIS = "4fb0b97752edc3049cba46a0fb0cfcf5fa51a0575136efeab3d2bc1e391296b1"
#: SHA-256 of its current shared basis (``basis.safetensors``: fitted on colour-permuted materials, factorised).
CURRENT_BASIS = "b15a34554d6f7c923269dff4ccf19c66f6bac0f38d3993d7ba59e6738825fc47"
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


def canonical(header: dict[str, Any]) -> bytes:
    return json.dumps(header, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode("utf-8")


def assemble(stored: bytes, payload: bytes, *, flags: int = 0, major: int = 1, minor: int = 1,
             crc_flags: int | None = None) -> bytes:
    """Preamble + stored header + payload; ``crc_flags`` computes the CRC over other flags (a flipped bit)."""
    def head(f: int) -> bytes:
        return MAGIC + struct.pack("<HHII", major, minor, f, len(stored))

    crc = zlib.crc32(stored, zlib.crc32(head(flags if crc_flags is None else crc_flags)))
    return head(flags) + struct.pack("<I", crc) + stored + payload


def zstd(data: bytes) -> bytes:
    import zstandard

    return zstandard.ZstdCompressor(level=19, write_content_size=True).compress(data)


def base_header(records: list[dict[str, Any]], *, dim: int = 2, dtype: str = "float32") -> dict[str, Any]:
    return {"created_by": "conformance vectors", "decoder": {"name": TEST_DECODER.name, "sha256": TEST_DECODER.sha256},
            "format": "bvae", "latent_dim": dim, "latent_dtype": dtype, "records": records}


def latent(name: str, mu: list[float], sigma: list[float], offset: int = 0, **extra: Any) -> tuple[dict, bytes]:
    payload = np.array([*mu, *sigma], dtype="<f4").tobytes()
    entry = {"crc32": zlib.crc32(payload), "kind": "latent", "length": len(payload), "name": name, "offset": offset}
    entry.update(extra)
    return entry, payload


def plain(records: list[tuple[dict, bytes]], **header_changes: Any) -> tuple[bytes, bytes]:
    """(stored header, payload) of records laid out contiguously."""
    entries, payloads, offset = [], [], 0
    for entry, payload in records:
        entries.append({**entry, "offset": offset})
        payloads.append(payload)
        offset += len(payload)
    header = base_header(entries)
    header.update(header_changes)
    return canonical(header), b"".join(payloads)


def invalid_vectors() -> dict[str, tuple[bytes, str, str]]:
    """name -> (file bytes, error class, what is wrong)."""
    good = latent("a", [0.5, -1.0], [0.25, 0.5])
    stored, payload = plain([good])
    valid = assemble(stored, payload)
    out: dict[str, tuple[bytes, str, str]] = {}

    def add(name: str, data: bytes, error: str, why: str) -> None:
        out[name] = (data, error, why)

    def header_with(**changes: Any) -> bytes:
        s, p = plain([good], **changes)
        return assemble(s, p)

    def with_entry(**changes: Any) -> bytes:
        entry, p = good
        s, p = plain([({**entry, **changes}, p)])
        return assemble(s, p)

    add("bad-magic", b"\x89BVAF" + valid[5:], "malformed", "wrong magic number")
    add("truncated-preamble", valid[:20], "malformed", "shorter than the 24-byte preamble")
    add("truncated-record", valid[:-1], "malformed", "the last record is one byte short")
    add("trailing-bytes", valid + b"\x00", "malformed", "one byte after the last record")
    flipped = bytearray(valid)
    flipped[24 + 5] ^= 0x01
    add("header-crc", bytes(flipped), "checksum", "one header bit flipped")
    flipped = bytearray(valid)
    flipped[-1] ^= 0x80
    add("record-crc", bytes(flipped), "checksum", "one payload bit flipped")
    add("flag-bit-flipped", assemble(stored, payload, flags=2, crc_flags=0), "checksum",
        "flag bit 1 set by corruption (CRC over the original flags): checksum wins over unsupported (§7)")
    add("unknown-flag", assemble(stored, payload, flags=2), "unsupported", "flag bit 1 set, CRC valid")
    add("major-version-2", assemble(stored, payload, major=2), "unsupported", "major version 2")
    add("unknown-kind", with_entry(kind="spline"), "unsupported", "record kind 'spline'")
    s, _ = plain([good], latent_dtype="bfloat16")
    add("unknown-dtype", assemble(s, payload), "unsupported", "latent_dtype 'bfloat16'")
    add("zstd-trailing-bytes", assemble(zstd(stored) + b"\x00\x00", payload, flags=1), "malformed",
        "two bytes after the header's zstandard frame")
    half = len(stored) // 2
    add("zstd-two-frames", assemble(zstd(stored[:half]) + zstd(stored[half:]), payload, flags=1), "malformed",
        "the header split over two zstandard frames (a joining decoder would read a valid header)")
    text = stored.decode()
    add("number-overflow", assemble(text.replace('"latent_dim":2', '"latent_dim":2,"x":1e999').encode(), payload),
        "malformed", "the number 1e999 (overflows binary64 to infinity)")
    add("integer-too-large", assemble(text.replace('"latent_dim":2', '"latent_dim":2,"x":9007199254740992').encode(),
        payload), "malformed", "the integer 2^53, beyond I-JSON's exact range")
    add("duplicate-key", assemble(text.replace('"latent_dim":2', '"latent_dim":2,"latent_dim":2').encode(), payload),
        "malformed", "the key latent_dim twice in one object")
    add("nan-mu", assemble(*plain([latent("a", [float("nan"), 0.0], [0.25, 0.5])])), "malformed",
        "mu[0] is NaN (record CRC valid)")
    add("sigma-zero", assemble(*plain([latent("a", [0.0, 0.0], [0.0, 0.5])])), "malformed",
        "sigma[0] is 0 (record CRC valid)")
    add("graft-dims-on-latent", with_entry(graft_dims=[0]), "malformed", "graft_dims on a latent record")
    graft_payload = np.array([0.5, -1.0, 0.25, 0.5, np.inf], dtype="<f4").tobytes()
    graft_entry = {"crc32": zlib.crc32(graft_payload), "graft_dims": [1], "kind": "graft",
                   "length": len(graft_payload), "name": "g", "offset": 0}
    add("graft-value-infinite", assemble(*plain([(graft_entry, graft_payload)])), "malformed",
        "a graft value is +infinity (record CRC valid)")
    add("decoder-name-missing", header_with(decoder={"sha256": TEST_DECODER.sha256}), "malformed",
        "decoder.name absent")
    add("created-by-number", header_with(created_by=3), "malformed", "created_by is the number 3")
    add("meta-relae-null", with_entry(meta={"relae": {"mapped": None}}), "malformed", "meta.relae.mapped is null")
    add("meta-relae-string", with_entry(meta={"relae": {"mapped": "x"}}), "malformed", "meta.relae.mapped is a string")
    add("meta-sha-type", with_entry(meta={"source_sha256": 7}), "malformed", "meta.source_sha256 is a number")
    add("layers-on-latent", with_entry(layers={"detail": {"transform": "dct3-ycc", "step": 0.1, "dtype": "int16",
                                                          "length": 1}}),
        "malformed", "a layers object on a latent record")
    add("meta-effort-string", with_entry(meta={"effort": "1"}), "malformed", "meta.effort is the string '1'")
    add("meta-effort-range", with_entry(meta={"effort": 4}), "malformed", "meta.effort is 4 (outside 0-3)")
    add("meta-rate-number", with_entry(meta={"rate": 64}), "malformed", "meta.rate is a number, not an object")
    add("meta-source-kind-number", with_entry(meta={"source_kind": 1}), "malformed", "meta.source_kind is a number")
    detail = detail_frame([1], 63 * 90 * 90)
    lay_payload = np.array([0.5, -1.0, 0.25, 0.5], dtype="<f4").tobytes() + detail
    lay_entry = {"crc32": zlib.crc32(lay_payload), "kind": "layered", "length": len(lay_payload), "name": "l",
                 "offset": 0, "layers": {"detail": {"dtype": "int16", "length": len(detail), "step": 0.1,
                                                    "transform": "dct3-ycc"}}}
    add("layered-unknown-transform", assemble(*plain([({**lay_entry, "layers": {"detail": {
        **lay_entry["layers"]["detail"], "transform": "wavelet"}}}, lay_payload)])), "unsupported",
        "a detail layer with transform 'wavelet'")
    add("layered-unknown-layer", assemble(*plain([({**lay_entry, "layers": {**lay_entry["layers"], "hologram": {}}},
                                                   lay_payload)])), "unsupported",
        "layers holding 'hologram' besides 'detail'")
    # Basis layer (since 1.2): mu as float32, sigma as one byte each, the basis step (float16) and coefficients.
    basis_payload = (np.array([0.5, -1.0], dtype="<f4").tobytes() + bytes([160, 176])
                     + np.float16(0.25).astype("<f2").tobytes() + bytes([3, 253, 0]))
    basis_entry = {"crc32": zlib.crc32(basis_payload), "kind": "layered", "length": len(basis_payload), "name": "b",
                   "offset": 0, "layers": {"sigma": "log2-u8", "basis": {"sha256": "cd" * 32, "count": 3}}}

    def basis_vector(layers: dict[str, Any], payload: bytes = basis_payload) -> bytes:
        return assemble(*plain([({**basis_entry, "layers": layers, "length": len(payload),
                                  "crc32": zlib.crc32(payload)}, payload)]))

    add("basis-unknown-sigma", basis_vector({**basis_entry["layers"], "sigma": "log2-u4"}), "unsupported",
        "sigma stored as 'log2-u4'")
    add("basis-unknown-field", basis_vector({**basis_entry["layers"], "basis": {
        **basis_entry["layers"]["basis"], "transform": "ica"}}), "unsupported",
        "a basis layer with a field 'transform'")
    add("basis-count-zero", basis_vector({**basis_entry["layers"], "basis": {"sha256": "cd" * 32, "count": 0}},
                                         basis_payload[:12]), "malformed", "a basis layer of 0 coefficients")
    add("basis-sha-upper", basis_vector({**basis_entry["layers"], "basis": {"sha256": "CD" * 32, "count": 3}}),
        "malformed", "a basis sha256 in upper-case hex")
    add("basis-length", basis_vector({**basis_entry["layers"], "basis": {"sha256": "cd" * 32, "count": 4}}),
        "malformed", "count 4 but 3 coefficient bytes (record length as the payload)")
    nan_step = basis_payload[:10] + np.float16(np.nan).astype("<f2").tobytes() + basis_payload[12:]
    add("basis-step-nan", basis_vector(basis_entry["layers"], nan_step), "malformed",
        "the basis step is NaN (record CRC valid)")
    # The basis layer's first vector (since 1.3).
    add("basis-first-negative", basis_vector({**basis_entry["layers"], "basis": {
        **basis_entry["layers"]["basis"], "first": -1}}), "malformed", "a basis layer whose first vector is -1")
    add("basis-first-string", basis_vector({**basis_entry["layers"], "basis": {
        **basis_entry["layers"]["basis"], "first": "8"}}), "malformed", "a basis layer whose first vector is '8'")
    add("basis-first-range", basis_vector({**basis_entry["layers"], "basis": {
        **basis_entry["layers"]["basis"], "first": 4094}}), "malformed",
        "first 4094 with count 3 runs past the 4096 vectors a basis may hold")
    # A projected base (since 1.6): P in [1, 4096].
    add("basis-project-zero", basis_vector({**basis_entry["layers"], "basis": {
        **basis_entry["layers"]["basis"], "project": 0}}), "malformed",
        "a basis layer projecting its base on 0 vectors (absent means no projection)")
    add("basis-project-bool", basis_vector({**basis_entry["layers"], "basis": {
        **basis_entry["layers"]["basis"], "project": True}}), "malformed",
        "a basis layer whose projection is true, not a number of vectors")
    zero_step = basis_payload[:10] + np.float16(0).astype("<f2").tobytes() + basis_payload[12:]
    add("basis-step-zero", basis_vector(basis_entry["layers"], zero_step), "malformed",
        "the basis step is 0 (record CRC valid)")
    # Compact mu and the shared sigma byte (since 1.4): mu as a float16 step and int8 values, one sigma byte.
    compact_payload = (np.float16(0.5).astype("<f2").tobytes() + bytes([2, 254]) + bytes([160])
                       + basis_payload[10:])
    compact_layers = {"mu": "int8", "sigma": "log2-u8-shared", "basis": basis_entry["layers"]["basis"]}
    add("compact-mu-unknown", basis_vector({**compact_layers, "mu": "int4"}, compact_payload), "unsupported",
        "mu stored as 'int4'")
    add("compact-mu-step-nan", basis_vector(compact_layers, np.float16(np.nan).astype("<f2").tobytes()
                                            + compact_payload[2:]), "malformed",
        "the compact mu step is NaN (record CRC valid)")
    add("compact-sigma-length", basis_vector(compact_layers, compact_payload[:5] + bytes([160])
                                             + compact_payload[5:]), "malformed",
        "a shared sigma (one byte) but two sigma bytes (record length as the payload)")
    # Compact mu on the fixed grid (since 1.5): D int8 values and no step; a step in front is 2 bytes too many.
    add("compact-mu-fixed-with-step", basis_vector({**compact_layers, "mu": "int8-fixed"}, compact_payload),
        "malformed", "mu on the fixed grid (no step) followed by a step's 2 bytes (record length as the payload)")
    short = detail_frame([1], 63 * 90 * 90 - 1)
    short_payload = lay_payload[:16] + short
    add("layered-content-size", assemble(*plain([({**lay_entry, "crc32": zlib.crc32(short_payload),
                                                   "length": len(short_payload), "layers": {"detail": {
                                                       **lay_entry["layers"]["detail"], "length": len(short)}}},
                                                  short_payload)])),
        "malformed", "a detail frame declaring one int16 fewer than 63*90*90 (record CRC valid)")
    add("record-offset-gap", assemble(canonical(base_header([{**good[0], "offset": 4}])), b"\0" * 4 + payload),
        "malformed", "first record at offset 4, not 0 (the file is 4 bytes longer to match)")
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
        ("name-too-long", "x" * 256, "a name of 256 characters"),
    ]:
        add(label, with_entry(name=name), "malformed", why)
    lone = text.replace('"name":"a"', '"name":"a\\ud800"').encode()
    add("name-lone-surrogate", assemble(lone, payload), "malformed", "a name holding the lone surrogate \\ud800")
    add("name-case-twins", assemble(*plain([latent("Gold", [0, 0], [1, 1]), latent("gold", [0, 0], [1, 1])])),
        "malformed", "names 'Gold' and 'gold' (equal after case folding)")
    add("name-duplicate", assemble(*plain([latent("a", [0, 0], [1, 1]), latent("a", [0, 0], [1, 1])])),
        "malformed", "the name 'a' twice")
    bomb = zstd(b"[" + b"{}," * (16 * 2**20 // 3 - 1) + b"{}]")
    add("header-amplification", assemble(bomb, b"", flags=1), "malformed",
        f"a {len(bomb) + 24}-byte file whose header expands to 16 MiB of [{{}},{{}},...]: more JSON containers "
        "than the limit")
    deep = canonical(base_header([good[0]])).replace(b'"created_by":"conformance vectors"',
                                                     b'"created_by":"x","deep":' + b"[" * 65 + b"]" * 65)
    add("header-too-deep", assemble(deep, payload), "malformed", "JSON nested 66 levels deep")
    return out


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
    from brdfcodec.layers.detail import N_DETAIL_VALUES, DetailLayer
    from brdfcodec.layers.record import LayeredRecord

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
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.detail import N_DETAIL_VALUES, DetailLayer
    from brdfcodec.layers.record import LayeredRecord

    layer = DetailLayer(0.125, "int16", detail_frame([8, -4, 2], N_DETAIL_VALUES)) if detail else None
    basis = BasisLayer(sha256, 0.5, np.array([12, -7, 3, 0, -1], dtype=np.int8), first, project)
    storage = {"compact_mu": True, "shared_sigma": True, "fixed_mu_grid": fixed_grid} if compact_base else {
        "compact_sigma": True}
    return LayeredRecord(name, mu, sigma, {"effort": 1}, detail=layer, basis=basis, **storage)


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
                                     basis_record("reference.basis-current", halves16(8), np.full(8, 0.125),
                                                  CURRENT_BASIS, first=8, compact_base=True, fixed_grid=True,
                                                  project=50)],
                                    SHIPPED_DECODER, "float16", False),
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
    }


def describe(record: LatentRecord | GraftRecord) -> dict[str, Any]:
    item: dict[str, Any] = {"name": record.name, "kind": record.kind, "mu": record.mu.tolist(),
                            "sigma": record.sigma.tolist(), "meta": dict(record.meta)}
    if isinstance(record, GraftRecord):
        item["graft_dims"] = list(record.graft_dims)
        item["graft_values"] = record.graft_values.tolist()
    if record.kind == "layered":
        from brdfcodec.layers.record import layers_entry

        item["layers"] = layers_entry(record)  # type: ignore[arg-type]
    return item


def reference_values(records: list) -> dict[str, list[float]]:
    """Decoded values at REFERENCE_ENTRIES for each record, with the shipped model (masked as -1)."""
    from brdfcodec.codec import BrdfDecoder

    decoder = BrdfDecoder()
    assert decoder.reference == SHIPPED_DECODER, "the shipped model changed: regenerate and review the vectors"
    values = {}
    for record in records:
        table = decoder.table(record)
        values[record.name] = [float(table[tuple(e)]) for e in REFERENCE_ENTRIES]
    return values


def generate(folder: Path, *, with_reference: bool = True) -> dict[str, Any]:
    """Write every vector and ``manifest.json`` into ``folder``; return the manifest."""
    (folder / "valid").mkdir(parents=True, exist_ok=True)
    (folder / "invalid").mkdir(parents=True, exist_ok=True)
    manifest: dict[str, Any] = {
        "format_version": "1.6",
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
        manifest["valid"].append({
            "file": f"valid/{name}.bvae", "decoder_sha256": decoder.sha256, "latent_dtype": dtype,
            "header_compressed": bool(compress), "records": [describe(r) for r in records],
        })
        if name == "reference-decode" and with_reference:
            manifest["decode"] = {
                "file": f"valid/{name}.bvae", "entries": REFERENCE_ENTRIES, "rtol": DECODE_RTOL, "atol": DECODE_ATOL,
                "masked": "unmeasured", "units": "stored MERL units (float32)",
                "values": reference_values(records),
            }
        if name == "reference-decode-layers" and with_reference:
            manifest["decode_layers"] = {
                "file": f"valid/{name}.bvae", "entries": REFERENCE_ENTRIES, "rtol": DECODE_RTOL, "atol": DECODE_ATOL,
                "masked": "unmeasured", "units": "stored MERL units (float32)", "basis_sha256": SHIPPED_BASIS,
                "values": reference_values(records),
            }
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
