"""Fuzzing of the surfaces the second hardening pass covered (issue 37): layered records, RGL headers, studio bodies.

A short run by default. ``BVAE_FUZZ=long`` (or ``BVAE_FUZZ_EXAMPLES=N``) makes it long, as in
``tests/test_bvae_fuzz.py``; the mutation run then tries at least 100,000 inputs::

    BVAE_FUZZ=long python -m pytest -q -s tests/test_fuzz_pass2.py -k mutation_run

and prints its counts (``BVAE_FUZZ_REPORT=FILE`` also writes them as JSON). Invariants, everywhere:

* a ``.bvae`` input is refused with a :class:`~brdfcodec.errors.BrdfcodecError` by what ``bvae info`` runs
  (:func:`brdfcodec.cli.info_command.describe_file`), or it is accepted and then opens for decoding and decodes
  (every record) with the shipped decoder without any error: ``info`` never accepts what decoding refuses;
* an RGL ``.bsdf`` input is refused with a :class:`~brdfcodec.errors.SourceFormatError` by the header checks
  (what ``bvae info`` says "reads no" to and ``bvae compress`` refuses before Mitsuba), or Mitsuba's
  ``measured`` plugin loads and evaluates it without error (no crash, no refusal);
* a studio request body gets a 4xx :class:`~brdfcodec.studio.StudioError` or is used, never another exception.
"""

from __future__ import annotations

import functools
import json
import os
import random
import struct
import sys
import time
import zlib
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tensor_files import small_rgl_fields, tensor_file

from brdfcodec.errors import BrdfcodecError, SourceFormatError

LONG = os.environ.get("BVAE_FUZZ") == "long"


def _examples(default: int) -> int:
    if os.environ.get("BVAE_FUZZ_EXAMPLES"):
        return int(os.environ["BVAE_FUZZ_EXAMPLES"])
    return default * 50 if LONG else default


def fuzz(default: int) -> settings:
    return settings(max_examples=_examples(default), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])


# --------------------------------------------------------------------------- seeds


_STATE: dict[str, Any] = {}


def _decoder():  # type: ignore[no-untyped-def]
    if "decoder" not in _STATE:
        from brdfcodec.codec import BrdfDecoder

        _STATE["decoder"] = BrdfDecoder()
    return _STATE["decoder"]


def _detail(seed: int, step: float = 0.2):  # type: ignore[no-untyped-def]
    from brdfcodec.layers.detail import encode_detail

    rng = np.random.default_rng(seed)
    residual = np.zeros((63, 90, 90))
    residual[:, :12, :12] = rng.normal(0.0, 0.05, (63, 12, 12))  # a small frame: a few kB
    return encode_detail(residual, step)


def bvae_seeds() -> list[bytes]:
    """Valid files holding every record kind and every layered form (base storage, basis, projection, detail),
    written by the library's writer with the shipped decoder and its shared basis."""
    if "seeds" in _STATE:
        return _STATE["seeds"]
    from brdfcodec.format.bvae import GraftRecord, LatentRecord, encode_bvae
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer

    decoder = _decoder()
    sha = decoder.shared_basis.sha256
    rng = np.random.default_rng(37)

    def code() -> np.ndarray:
        return rng.normal(0.0, 1.0, 8)

    def basis(k: int, first: int = 8, project: int = 0) -> BasisLayer:
        return BasisLayer(sha, 0.125, rng.integers(-127, 128, k).astype(np.int8), first, project)

    sigma = np.full(8, 0.5)
    layered = [
        LayeredRecord("detail", code(), sigma, detail=_detail(1)),
        LayeredRecord("basis", code(), sigma, basis=basis(12), compact_sigma=True),
        LayeredRecord("both", code(), sigma, basis=basis(6, 0), detail=_detail(2, 0.5), compact_mu=True,
                      shared_sigma=True),
        LayeredRecord("fixed", np.clip(code(), -3, 3), sigma, basis=basis(20, 8, 50), compact_mu=True,
                      fixed_mu_grid=True, shared_sigma=True),
        LayeredRecord("projected", code(), sigma, basis=basis(4, 8, 50), compact_sigma=True),
    ]
    seeds = [
        encode_bvae([LatentRecord("plain", code(), sigma)], decoder.reference),
        encode_bvae([LatentRecord("half", code(), sigma)], decoder.reference, latent_dtype="float16"),
        encode_bvae([GraftRecord("graft", code(), sigma, (0, 1), [0.5, -0.5])], decoder.reference),
        encode_bvae([LatentRecord("lib-a", code(), sigma, {"source_kind": "analytic", "effort": 1}),
                     GraftRecord("lib-b", code(), sigma, (2,), [1.0])], decoder.reference),
        *(encode_bvae([record], decoder.reference) for record in layered),
        encode_bvae(layered[1:3], decoder.reference, latent_dtype="float16"),
    ]
    _STATE["seeds"] = seeds
    return seeds


def _crc_positions(data: bytes) -> tuple[int, int | None]:
    """(header length, position of the payload CRC-32 in the file, if found): where to recompute CRCs."""
    from brdfcodec.format.bvae import PREAMBLE_SIZE

    header_length = struct.unpack_from("<I", data, 16)[0]
    records = PREAMBLE_SIZE + header_length
    needle = struct.pack("<I", zlib.crc32(data[records:]))
    position = data.find(needle, PREAMBLE_SIZE, records)
    return header_length, (position if position >= 0 else None)


def fix_crcs(data: bytearray, header_length: int, payload_crc_at: int | None) -> None:
    """Recompute the payload CRC-32 (where it was found in the seed) and the header CRC-32 in place."""
    from brdfcodec.format.bvae import PREAMBLE_SIZE

    records = PREAMBLE_SIZE + header_length
    if payload_crc_at is not None and payload_crc_at + 4 <= records <= len(data):
        struct.pack_into("<I", data, payload_crc_at, zlib.crc32(bytes(data[records:])))
    if records <= len(data):
        struct.pack_into("<I", data, 20, zlib.crc32(bytes(data[PREAMBLE_SIZE:records]), zlib.crc32(bytes(data[:20]))))


def mutate_bvae(seed: bytes, rng: random.Random) -> tuple[bytes, str]:
    """One mutation of a valid file, and its kind."""
    data = bytearray(seed)
    header_length, crc_at = _crc_positions(seed)
    records = 24 + header_length
    how = rng.random()
    if how < 0.08:
        return bytes(data[: rng.randrange(len(data))]), "truncate"
    if how < 0.14:
        at = rng.randrange(len(data) + 1)
        return bytes(data[:at] + bytes(rng.randrange(256) for _ in range(rng.randint(1, 8))) + data[at:]), "insert"
    if how < 0.22:
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        return bytes(data), "bit flip"
    # Byte changes under recomputed CRCs: they reach the checks behind the CRCs (values, layers, frames).
    region = rng.random()
    count = rng.choice((1, 1, 1, 2, 3))
    for _ in range(count):
        if region < 0.6 and len(data) > records:
            at = rng.randrange(records, len(data))  # a payload byte: values, steps, coefficients, frames
        else:
            at = rng.randrange(24, records)  # a header byte: fields, forms, descriptors
        if at in range(crc_at or -10, (crc_at or -10) + 4):
            continue
        data[at] = rng.choice((0, 0xFF, 0x7F, 0x80, data[at] ^ 0xFF, rng.randrange(256)))
    fix_crcs(data, header_length, crc_at)
    return bytes(data), "byte change, CRCs recomputed" if region < 0.6 else "header change, CRC recomputed"


def _structure(path: Path) -> tuple:
    """What decides whether an accepted file decodes, besides its values: kinds, layer forms and numbers, the basis
    step and the detail frames (values are checked finite at read; the decoder clamps whatever they decode to)."""
    from brdfcodec.format.bvae import read_bvae

    parsed = read_bvae(path)
    return (parsed.header.decoder.sha256, parsed.header.latent_dim, *(
        (r.kind, getattr(r, "graft_dims", ()), json.dumps(parsed.header.entry(r.name).layers, sort_keys=True),
         None if getattr(r, "detail", None) is None else hash(r.detail.data)) for r in parsed.records))


def check_bvae(data: bytes, path: Path, decode_all: set | None = None) -> str:
    """Run the invariant on one input; returns the outcome ("refused", "accepted") or raises AssertionError.

    With ``decode_all`` (a set the caller keeps), an accepted file whose structure was decoded before is decoded
    only now and then: the long run's time goes to new inputs rather than to the network."""
    from brdfcodec.cli.info_command import describe_file
    from brdfcodec.codec import MaterialLibrary

    path.write_bytes(data)
    try:
        summary = describe_file(path)  # what `bvae info` runs: header, records and their layers, the model's basis
    except BrdfcodecError:
        return "refused"
    except Exception as error:  # noqa: BLE001 - the invariant: typed errors only
        raise AssertionError(f"untyped {type(error).__name__} from info: {error}") from error
    if summary["decoder"]["installed_at"] is None:  # info says so: "NOT INSTALLED" (a changed decoder hash)
        return "accepted, decoder not installed"
    if decode_all is not None:  # decode every new structure (forms, layer numbers, frames), and a sample of the rest
        key = _structure(path)
        if key in decode_all and random.random() >= 0.02:
            return "accepted (structure decoded before)"
        decode_all.add(key)
    try:
        with MaterialLibrary(path, decoder=_decoder()) as library:
            for name in library.names:
                table = library[name].table(phi_d_bins=[0, 90])
                assert np.isfinite(table).all()
    except Exception as error:  # noqa: BLE001
        raise AssertionError(f"info accepted what decoding refused: {type(error).__name__}: {error}") from error
    return "accepted"


# --------------------------------------------------------------------------- RGL headers

_SHAPE_VALUES = (0, 1, 2, 3, 7, 8, 2**31, 2**32, 2**32 + 1, 2**62, 2**63, 2**63 + 1, 2**64 - 1)


def rgl_seed() -> bytes:
    return tensor_file(small_rgl_fields())


def _field_starts(data: bytes) -> list[tuple[int, int]]:
    """(position of the field's ndim, ndim) for every field of a valid tensor file."""
    out, at = [], 18
    for _ in range(struct.unpack_from("<I", data, 14)[0]):
        length = struct.unpack_from("<H", data, at)[0]
        at += 2 + length
        ndim = struct.unpack_from("<H", data, at)[0]
        out.append((at, ndim))
        at += 2 + 1 + 8 + 8 * ndim
    return out


def mutate_rgl(seed: bytes, rng: random.Random) -> tuple[bytes, str]:
    data = bytearray(seed)
    fields = _field_starts(seed)
    at, ndim = rng.choice(fields)
    how = rng.random()
    if how < 0.35 and ndim:  # a declared shape entry, up to 2^64 − 1
        struct.pack_into("<Q", data, at + 11 + 8 * rng.randrange(ndim),
                         rng.choice(_SHAPE_VALUES) if rng.random() < 0.7 else rng.randrange(2**64))
        return bytes(data), "shape"
    if how < 0.5:
        data[at + 2] = rng.randrange(256) if rng.random() < 0.3 else rng.randrange(12)
        return bytes(data), "type code"
    if how < 0.6:
        near = struct.unpack_from("<Q", data, at + 3)[0] + rng.randint(-9, 9)
        choices = (0, len(data) - 4, len(data), 2**63, rng.randrange(2**64), near)
        struct.pack_into("<Q", data, at + 3, rng.choice(choices))
        return bytes(data), "offset"
    if how < 0.68:
        struct.pack_into("<H", data, at, rng.choice((0, 1, 3, 4, 5, 9, 65535)))
        return bytes(data), "ndim"
    if how < 0.74:
        position = rng.randrange(12, 18)
        data[position] = rng.randrange(256)
        return bytes(data), "version or count"
    if how < 0.8:
        return bytes(data[: rng.randrange(len(data))]), "truncate"
    if how < 0.9:  # a value in the data: NaN, infinity, negative, huge
        first_data = min(struct.unpack_from("<Q", data, a + 3)[0] for a, _ in fields)
        position = rng.randrange(first_data, len(data) - 4)
        struct.pack_into("<f", data, position, rng.choice((float("nan"), float("inf"), -1.0, 3e38, 0.0)))
        return bytes(data), "data value"
    for _ in range(rng.randint(1, 4)):
        data[rng.randrange(12, fields[-1][0] + 11)] = rng.randrange(256)
    return bytes(data), "header bytes"


def _mitsuba():  # type: ignore[no-untyped-def]
    if "mitsuba" not in _STATE:
        try:
            import mitsuba as mi
        except ImportError:
            _STATE["mitsuba"] = None
        else:
            mi.set_variant("scalar_rgb")
            mi.set_log_level(mi.LogLevel.Error)
            _STATE["mitsuba"] = mi
    return _STATE["mitsuba"]


def check_rgl(data: bytes, path: Path) -> str:
    from brdfcodec.io.rgl import check_supported, read_rgl_header

    path.write_bytes(data)
    try:
        check_supported(read_rgl_header(path))
    except SourceFormatError:
        return "refused"
    except Exception as error:  # noqa: BLE001
        raise AssertionError(f"untyped {type(error).__name__} from the RGL checks: {error}") from error
    mi = _mitsuba()
    if mi is None:
        return "accepted"
    try:  # what `bvae compress` hands to Mitsuba: it must load and evaluate
        bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
        si = mi.SurfaceInteraction3f()
        si.sh_frame = mi.Frame3f(mi.Normal3f(0.0, 0.0, 1.0))
        for wi, wo in (((0.0, 0.0, 1.0), (0.0, 0.0, 1.0)), ((0.6, 0.0, 0.8), (-0.3, 0.4, 0.866))):
            si.wi = mi.Vector3f(*wi)
            bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*wo))
    except Exception as error:  # noqa: BLE001
        raise AssertionError(f"the checks accepted what Mitsuba refused: {str(error).splitlines()[0]}") from error
    return "accepted"


# --------------------------------------------------------------------------- the long mutation run


@pytest.mark.slow
def test_mutation_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Mutated ``.bvae`` files (every record kind) and ``.bsdf`` headers: zero crashes, zero untyped
    exceptions, zero inputs that ``info`` accepts and decoding refuses (at least 100,000 with ``BVAE_FUZZ=long``)."""
    from brdfcodec.models import registry

    monkeypatch.setattr(registry, "find_model", functools.lru_cache(maxsize=64)(registry.find_model))  # no rescans
    total = int(os.environ.get("BVAE_FUZZ_EXAMPLES") or (120_000 if LONG else 400))
    rng = random.Random(int(os.environ.get("BVAE_FUZZ_SEED", "37")))
    seeds, rgl = bvae_seeds(), rgl_seed()
    for seed in seeds:  # the seeds themselves are valid
        assert check_bvae(seed, tmp_path / "seed.bvae") == "accepted"
    assert check_rgl(rgl, tmp_path / "seed_rgb.bsdf") == "accepted"
    counts: Counter[str] = Counter()
    failures: list[str] = []
    start = time.monotonic()
    structures: set = set()
    for i in range(total):
        if i % 10 < 7:
            data, how = mutate_bvae(rng.choice(seeds), rng)
            kind, path = "bvae", tmp_path / "fuzz.bvae"
            check = functools.partial(check_bvae, decode_all=structures)
        else:
            data, how = mutate_rgl(rgl, rng)
            kind, check, path = "bsdf", check_rgl, tmp_path / "fuzz_rgb.bsdf"  # type: ignore[assignment]
        try:
            outcome = check(data, path)
        except AssertionError as error:
            outcome = "FAILED"
            if len(failures) < 20:
                failures.append(f"{kind} ({how}): {error}")
                (tmp_path / f"failure-{len(failures)}.{kind}").write_bytes(data)
        counts[f"{kind} {outcome}"] += 1
        counts[f"{kind} {how}"] += 1
        if LONG and i % 5000 == 4999:
            print(f"{i + 1} inputs, {time.monotonic() - start:.0f} s: {dict(counts)}", file=sys.stderr, flush=True)
    report = {"inputs": total, "seconds": round(time.monotonic() - start, 1), "counts": dict(sorted(counts.items())),
              "failures": failures}
    print(json.dumps(report, indent=1))
    if os.environ.get("BVAE_FUZZ_REPORT"):
        Path(os.environ["BVAE_FUZZ_REPORT"]).write_text(json.dumps(report, indent=1) + "\n")
    assert not failures, failures
    assert counts["bvae accepted"] and counts["bvae refused"] and counts["bsdf refused"] and counts["bsdf accepted"]


# --------------------------------------------------------------------------- properties


@fuzz(40)
@given(st.binary(max_size=64), st.sampled_from(["append", "prepend", "replace", "cut", "frame"]))
@pytest.mark.slow
def test_fuzz_detail_frames(extra: bytes, how: str) -> None:
    """A detail layer's bytes that are not exactly one whole frame: a format error naming the record, at read."""
    import zstandard

    from brdfcodec.errors import BvaeFormatError
    from brdfcodec.format.bvae import encode_bvae, parse_bvae
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.detail import DetailLayer

    frame = _detail(3).data
    data = {"append": frame + extra, "prepend": extra + frame, "replace": extra or b"\0",
            "cut": frame[: max(1, len(frame) - 1 - len(extra))],
            "frame": frame + zstandard.ZstdCompressor(write_content_size=True).compress(extra)}[how]
    record = LayeredRecord("m", np.zeros(8), np.ones(8), detail=DetailLayer(0.2, "int16", data))
    file = encode_bvae([record], _decoder().reference)
    if data == frame:
        assert parse_bvae(file).records[0].detail.data == frame
        return
    with pytest.raises(BvaeFormatError, match="'m'"):
        parse_bvae(file, "fuzz.bvae")


@fuzz(60)
@given(st.integers(1, 300), st.integers(0, 300), st.integers(0, 300), st.booleans())
def test_fuzz_basis_fields_against_the_model(count: int, first: int, project: int, unknown: bool) -> None:
    """Any count, first vector and projection a file may declare: opening it for decoding either succeeds and
    decodes, or refuses with a BasisError / BasisMismatchError (both BrdfcodecErrors)."""
    from brdfcodec.errors import BasisError, BasisMismatchError
    from brdfcodec.format.bvae import encode_bvae, parse_bvae
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import BasisLayer

    decoder = _decoder()
    sha = "00" * 32 if unknown else decoder.shared_basis.sha256
    layer = BasisLayer(sha, 0.125, np.ones(count, dtype=np.int8), first, project)
    parsed = parse_bvae(encode_bvae([LayeredRecord("m", np.zeros(8), np.ones(8), basis=layer)], decoder.reference))
    fits = not unknown and first + count <= decoder.shared_basis.count and project <= decoder.shared_basis.count
    try:
        decoder.check(parsed.header, "fuzz.bvae")
    except (BasisError, BasisMismatchError) as error:
        assert not fits and "fuzz.bvae" in str(error)
        assert isinstance(error, BasisMismatchError) == unknown
        return
    assert fits
    assert np.isfinite(decoder.decode(parsed.records[0], phi_d_bins=[90])).all()


@fuzz(150)
@given(st.sampled_from(["sigma", "ndf", "vndf", "luminance", "rgb", "theta_i", "phi_i", "jacobian", "description"]),
       st.lists(st.sampled_from(_SHAPE_VALUES) | st.integers(0, 2**64 - 1), min_size=0, max_size=6),
       st.sampled_from([1, 2, 5, 9, 10, 11]))
def test_fuzz_rgl_declared_shapes(field: str, shape: list[int], code: int) -> None:
    """Any declared shape (entries up to 2^64 − 1) and type code of a field the plugin reads: a SourceFormatError
    naming the file, or a file whose every field lies in the file with the plugin's layout."""
    import tempfile

    from brdfcodec.io.rgl import check_supported, read_rgl_header

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz_rgb.bsdf"
        path.write_bytes(tensor_file(small_rgl_fields(), shapes={field: shape}, codes={field: code}))
        try:
            header = read_rgl_header(path)
            check_supported(header)
        except SourceFormatError as error:
            assert str(path) in str(error)
            return
        size = path.stat().st_size
        assert all(f.offset + f.nbytes <= size for f in header.fields.values())
        assert header.fields[field].count == int(np.prod(header.fields[field].shape, dtype=object))


_json_leaves = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8)
_json = st.recursive(_json_leaves, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=6), c,
                                                                                         max_size=4), max_leaves=20)
_bodies = st.fixed_dictionaries({}, optional={
    "z": st.lists(st.floats() | st.integers(), min_size=7, max_size=9) | _json,
    "graft": st.none() | st.lists(st.floats() | st.integers(), max_size=3) | _json,
    "file": st.sampled_from(["a.bvae", "CON.bvae", "x.png\n", "..", "a.exr", "nul.binary"]) | st.text(max_size=12),
    "name": st.text(max_size=12) | _json,
    "edit": st.fixed_dictionaries({}, optional={"t": st.floats() | _json, "dims_from_a": _json,
                                                "changed": st.lists(st.floats() | st.integers(), max_size=4),
                                                "manifold": _json, "sampled": _json}) | _json,
    "overwrite": _json,
})


def _studio_server(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    if "studio" not in _STATE:
        pytest.importorskip("starlette", reason="the studio needs the studio extra (starlette, uvicorn)")
        from brdfcodec.format.bvae import LatentRecord, write_bvae
        from brdfcodec.studio.catalogue import Catalogue
        from brdfcodec.studio.server import StudioServer

        folder = tmp_path_factory.mktemp("studio-fuzz")
        library = folder / "lib.bvae"
        write_bvae(library, [LatentRecord(f"m{i}", np.full(8, 0.1 * i), np.ones(8)) for i in range(3)],
                   _decoder().reference)
        saves = folder / "saves"
        saves.mkdir()
        _STATE["studio"] = StudioServer(Catalogue([str(library)]), save_dir=saves)
    return _STATE["studio"]


@fuzz(150)
@given(body=_bodies | _json, raw=st.booleans(), route=st.sampled_from(["decode", "save"]))
def test_fuzz_studio_bodies(tmp_path_factory: pytest.TempPathFactory, body: Any, raw: bool, route: str) -> None:
    """A request body, parsed as the server parses it and then used: a StudioError (4xx), or a result."""
    from brdfcodec.studio import StudioError
    from brdfcodec.studio.server import _parse_json

    server = _studio_server(tmp_path_factory)
    text = json.dumps(body, allow_nan=True).encode()  # NaN, Infinity and huge integers included
    if raw:
        text = text.replace(b"1", b"1" * 30, 1)
    try:
        parsed = _parse_json(text)
        if not isinstance(parsed, dict):
            return
        if route == "decode":
            server.decode_slices(parsed)
        else:
            for target in server.save_dir.iterdir():
                target.unlink()
            server.save(parsed)
    except StudioError as error:
        assert 400 <= error.status < 500
    except (ValueError, RecursionError):
        assert route and True  # refused by the parser: the server answers 400 "not valid JSON"
