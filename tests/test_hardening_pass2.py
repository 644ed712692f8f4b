"""Regression tests of the second hardening pass (issue 37): each defect the red-team found, rebuilt here.

The reproductions in ``../shared/redteam-2/`` are not needed: every crafted file is generated in the test
(the ``.bvae`` ones with the test's own tiny model, the ``.bsdf`` ones from a small synthetic tensor file).
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from tensor_files import field_shape_position, small_rgl_fields, tensor_file

from brdfcodec.cli import main
from brdfcodec.errors import BrdfcodecError, SourceFormatError
from brdfcodec.io.rgl import check_supported, read_rgl_header

if TYPE_CHECKING:
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.layers.basis import BasisLayer
    from brdfcodec.layers.detail import DetailLayer

REPO_ROOT = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- 1. RGL files


def _rgl(tmp_path: Path, name: str = "crafted_rgb.bsdf", **options: object) -> Path:
    path = tmp_path / name
    path.write_bytes(tensor_file(small_rgl_fields(), **options))  # type: ignore[arg-type]
    return path


@pytest.mark.parametrize("shape", [
    [1, 3, 2**31, 2**31],  # the red-team file: int64 product wraps to 0
    [1, 3, 2**32, 2**32],
    [1, 3, 2**63, 2],
    [1, 3, 0, 2**63],  # an empty dimension: 0 bytes, but not a grid
])
def test_rgl_declared_shape_that_overflows_is_refused_before_mitsuba(tmp_path: Path, shape: list[int],
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    path = _rgl(tmp_path, shapes={"vndf": shape})
    with pytest.raises(SourceFormatError, match="'vndf'") as caught:
        check_supported(read_rgl_header(path))
    assert str(path) in str(caught.value)
    assert main(["info", str(path)]) in (0, 1)
    out = capsys.readouterr()
    assert "reads yes" not in out.out and "vndf" in out.out + out.err


@pytest.mark.slow
def test_rgl_overflowing_shape_does_not_crash_compress(tmp_path: Path) -> None:
    """The red-team file killed ``bvae compress`` by SIGSEGV inside Mitsuba: run it in a child process."""
    path = _rgl(tmp_path, shapes={"vndf": [1, 3, 2**31, 2**31]})
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    done = subprocess.run([sys.executable, "-m", "brdfcodec", "compress", str(path), "-o", str(tmp_path / "o.bvae")],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 1, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "'vndf'" in lines[0]
    assert not (tmp_path / "o.bvae").exists()


@pytest.mark.parametrize(("change", "field"), [
    ({"codes": {"vndf": 11}}, "vndf"),  # float64 declared over float32 data
    ({"codes": {"theta_i": 1}}, "theta_i"),
    ({"shapes": {"ndf": [16]}}, "ndf"),
    ({"shapes": {"ndf": [1, 16]}}, "ndf"),
    ({"shapes": {"vndf": [1, 2, 8, 8]}}, "vndf"),  # elevations disagree with theta_i
    ({"shapes": {"luminance": [1, 3, 2, 8]}}, "luminance"),  # not square
    ({"shapes": {"rgb": [1, 3, 4, 4, 3]}}, "rgb"),
    ({"shapes": {"jacobian": [2]}}, "jacobian"),
    ({"shapes": {"description": [23, 1]}}, "description"),
])
def test_rgl_fields_the_measured_plugin_reads_are_checked(tmp_path: Path, change: dict, field: str,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    fields = small_rgl_fields()
    shapes = change.get("shapes", {})
    if field == "vndf" and "shapes" in change:  # keep the byte range inside the file
        fields["vndf"] = fields["vndf"][:, :2]
    path = tmp_path / "crafted_rgb.bsdf"
    path.write_bytes(tensor_file(fields, shapes=shapes, codes=change.get("codes")))
    with pytest.raises(SourceFormatError, match=f"'{field}'") as caught:
        check_supported(read_rgl_header(path))
    assert str(path) in str(caught.value)
    if main(["info", str(path)]) == 0:  # info describes it, and says it cannot be read
        assert "reads no: " in capsys.readouterr().out


@pytest.mark.parametrize(("field", "value", "what"), [
    ("theta_i", np.nan, "non-finite"),
    ("vndf", np.inf, "non-finite"),
    ("luminance", -1.0, "negative"),
    ("rgb", np.nan, "non-finite"),
])
def test_rgl_field_values_are_checked(tmp_path: Path, field: str, value: float, what: str) -> None:
    fields = small_rgl_fields()
    fields[field] = fields[field].copy()
    fields[field].reshape(-1)[1] = value
    path = tmp_path / "values_rgb.bsdf"
    path.write_bytes(tensor_file(fields))
    with pytest.raises(SourceFormatError, match=f"'{field}' holds {what}"):
        check_supported(read_rgl_header(path))
    fields = small_rgl_fields()
    fields["theta_i"] = fields["theta_i"][::-1].copy()
    path.write_bytes(tensor_file(fields))
    with pytest.raises(SourceFormatError, match="'theta_i' is not strictly increasing"):
        check_supported(read_rgl_header(path))


def test_rgl_duplicate_fields_and_versions_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "version_rgb.bsdf"
    path.write_bytes(tensor_file(small_rgl_fields(), version=(2, 0)))
    with pytest.raises(SourceFormatError, match="version 2.0"):
        read_rgl_header(path)
    raw = bytearray(tensor_file(small_rgl_fields()))
    at = raw.index(struct.pack("<H", 3) + b"ndf")
    raw[at + 2 : at + 5] = b"rgb"  # 'rgb' twice: which one Mitsuba reads is not ours to guess
    path.write_bytes(bytes(raw))
    with pytest.raises(SourceFormatError, match="'rgb' appears twice"):
        read_rgl_header(path)


def test_rgl_mitsuba_refusal_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (extra brdfcodec[rgl])")
    import mitsuba

    from brdfcodec.io import rgl
    dump = "Invalid file structure: TensorFile[\n" + "\n".join(f"  field {i}" for i in range(60)) + "\n]"

    def refuse(*args: object, **kwargs: object) -> None:
        raise RuntimeError(dump)

    path = _rgl(tmp_path)
    monkeypatch.setattr(mitsuba, "load_dict", refuse)
    with pytest.raises(SourceFormatError) as caught:
        rgl._evaluate_on_grid(path)
    message = str(caught.value)
    assert "\n" not in message and str(path) in message and "Invalid file structure" in message
    assert "field 3" not in message


def test_rgl_synthetic_file_is_read_by_mitsuba(tmp_path: Path) -> None:
    """The checks refuse nothing Mitsuba reads: the valid synthetic file is accepted and tabulated."""
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (extra brdfcodec[rgl])")
    from brdfcodec.io.rgl import read_rgl_bsdf
    from brdfcodec.runtime.mitsuba import LibLLVMNotFoundError, find_libllvm

    try:
        find_libllvm()
    except LibLLVMNotFoundError as error:
        pytest.skip(f"{error} (the scalar fallback takes minutes)")
    brdf = read_rgl_bsdf(_rgl(tmp_path))
    assert brdf.values.shape == (3, 90, 90, 180)


def test_rgl_shape_wrap_on_the_real_file(shared_dir: Path, tmp_path: Path) -> None:
    """The red-team construction on ``paper_white_rgb.bsdf`` itself."""
    source = shared_dir / "data" / "rgl" / "paper_white_rgb.bsdf"
    if not source.is_file():
        pytest.skip(f"real RGL measurement not found at {source}")
    data = bytearray(source.read_bytes())
    position = field_shape_position(bytes(data), b"vndf")
    struct.pack_into("<QQQQ", data, position, 1, 8, 2**31, 2**31)
    path = tmp_path / "paper_white_rgb.bsdf"
    path.write_bytes(bytes(data))
    with pytest.raises(SourceFormatError, match="'vndf'"):
        read_rgl_header(path)
    assert issubclass(SourceFormatError, BrdfcodecError)


# --------------------------------------------------------------------------- 2, 3. layered records


@pytest.fixture(scope="module")
def shipped_decoder() -> BrdfDecoder:
    from brdfcodec.codec import BrdfDecoder

    decoder = BrdfDecoder()
    assert decoder.shared_basis is not None and decoder.shared_basis.count < 4000
    return decoder


def _layered_file(tmp_path: Path, decoder: BrdfDecoder, *, detail: DetailLayer | None = None,
                  basis: BasisLayer | None = None, name: str = "gold") -> Path:
    """A one-record ``.bvae`` file written by the library's own writer, so every CRC and length is right."""
    from brdfcodec.format.bvae import write_bvae
    from brdfcodec.format.layered_record import LayeredRecord

    rng = np.random.default_rng(0)
    record = LayeredRecord(name, rng.normal(size=decoder.latent_dim), np.ones(decoder.latent_dim),
                           detail=detail, basis=basis)
    path = tmp_path / f"{name}.bvae"
    write_bvae(path, [record], decoder.reference)
    return path


def _detail_frame() -> tuple[bytes, str]:
    from brdfcodec.layers.detail import encode_detail

    layer = encode_detail(np.random.default_rng(1).normal(0.0, 0.05, (63, 90, 90)), 0.2)
    return layer.data, layer.dtype


def _skippable(payload: bytes) -> bytes:
    return struct.pack("<II", 0x184D2A50, len(payload)) + payload


@pytest.mark.parametrize("how", ["corrupt", "truncated", "two-frames", "trailing-garbage", "skippable-frame"])
@pytest.mark.slow
def test_broken_detail_layer_is_refused_at_read(tmp_path: Path, shipped_decoder: BrdfDecoder, how: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """A detail frame that is corrupt or truncated under a correct record CRC, or followed by anything:
    refused when the record is read (``info`` included), as a format error naming the file and the record."""
    from brdfcodec.errors import BvaeFormatError
    from brdfcodec.format.bvae import read_bvae
    from brdfcodec.layers.detail import DetailLayer

    frame, dtype = _detail_frame()
    corrupt = bytearray(frame)
    corrupt[9] ^= 0xFF
    data = {"corrupt": bytes(corrupt), "truncated": frame[: len(frame) // 2], "two-frames": frame + frame,
            "trailing-garbage": frame + b"\x00garbage", "skippable-frame": frame + _skippable(b"hidden")}[how]
    path = _layered_file(tmp_path, shipped_decoder, detail=DetailLayer(0.2, dtype, data))
    with pytest.raises(BvaeFormatError) as caught:
        read_bvae(path)
    assert str(path) in str(caught.value) and "'gold'" in str(caught.value) and "detail" in str(caught.value)
    assert main(["info", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "detail" in err[0]
    out = tmp_path / "out"
    assert main(["decompress", str(path), "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0]
    assert not out.exists() or not any(out.iterdir())


def test_a_good_detail_layer_still_reads_and_decodes(tmp_path: Path, shipped_decoder: BrdfDecoder) -> None:
    from brdfcodec.codec import MaterialLibrary
    from brdfcodec.layers.detail import DetailLayer

    frame, dtype = _detail_frame()
    path = _layered_file(tmp_path, shipped_decoder, detail=DetailLayer(0.2, dtype, frame))
    with MaterialLibrary(path) as library:
        assert library["gold"].table(phi_d_bins=[90]).shape == (3, 90, 90, 1)


def _basis_layer(decoder: BrdfDecoder, *, count: int = 5, first: int = 0, project: int = 0,
                 sha: str | None = None) -> BasisLayer:
    from brdfcodec.layers.basis import BasisLayer

    return BasisLayer(sha or decoder.shared_basis.sha256, 0.25, np.ones(count, dtype=np.int8), first, project)


@pytest.mark.parametrize(("past", "basis"), [
    ({"count": 1}, "own"),
    ({"count": 10, "first": -5}, "own"),
    ({"count": 5, "first": 8, "project": 1}, "own"),
    ({"count": 10, "first": -5}, "prefix"),  # an earlier basis the shipped one extends: its own size bounds it
    ({"count": 5, "first": 8, "project": 1}, "prefix"),
])
def test_basis_fields_beyond_the_shared_basis_are_refused_on_open(
        tmp_path: Path, shipped_decoder: BrdfDecoder, past: dict, basis: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    from brdfcodec.codec import MaterialLibrary
    from brdfcodec.errors import BasisError
    from brdfcodec.format.bvae import read_bvae

    assert shipped_decoder.manifest is not None
    if basis == "prefix":
        if not shipped_decoder.manifest.basis_prefixes:
            pytest.skip("the shipped model's basis extends no earlier one")
        sha, size = next(iter(shipped_decoder.manifest.basis_prefixes.items()))
    else:
        sha, size = shipped_decoder.shared_basis.sha256, shipped_decoder.shared_basis.count
    # Fields just past the basis' size: all of it and one more, 10 from 5 before its end, projected on one more.
    fields = {"count": size + past["count"]} if set(past) == {"count"} else (
        {"count": 10, "first": size + past["first"]} if "project" not in past else
        {"count": 5, "first": 8, "project": size + past["project"]})
    what = ("projected on {}".format(fields["project"]) if "project" in fields else
            "vectors {} to {}".format(fields.get("first", 0) + 1, fields.get("first", 0) + fields["count"]))
    path = _layered_file(tmp_path, shipped_decoder, basis=_basis_layer(shipped_decoder, sha=sha, **fields))
    with pytest.raises(BasisError, match=what) as caught:
        MaterialLibrary(path)
    assert isinstance(caught.value, BrdfcodecError) and str(path) in str(caught.value) and "'gold'" in str(caught.value)
    assert main(["info", str(path)]) == 1  # the model is installed: info refuses what decoding would
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "holds" in err[0]
    with pytest.raises(BrdfcodecError):  # decoding the record directly: typed too
        shipped_decoder.decode(read_bvae(path).records[0], phi_d_bins=[90])


@pytest.mark.parametrize("project", [0, 50])
def test_unknown_basis_hash_is_a_basis_mismatch_for_projected_records_too(tmp_path: Path, shipped_decoder: BrdfDecoder,
                                                                          project: int) -> None:
    from brdfcodec.codec import MaterialLibrary
    from brdfcodec.errors import BasisMismatchError
    from brdfcodec.format.bvae import read_bvae

    layer = _basis_layer(shipped_decoder, count=5, first=8, project=project, sha="00" * 32)
    path = _layered_file(tmp_path, shipped_decoder, basis=layer)
    with pytest.raises(BasisMismatchError, match="0" * 64) as caught:
        MaterialLibrary(path)
    assert str(path) in str(caught.value) and shipped_decoder.shared_basis.sha256 in str(caught.value)
    with pytest.raises(BasisMismatchError, match=shipped_decoder.shared_basis.sha256):
        shipped_decoder.decode(read_bvae(path).records[0])


def test_every_error_raised_on_bad_basis_input_is_a_brdfcodec_error() -> None:
    from brdfcodec.errors import BasisError, BasisMismatchError
    from brdfcodec.layers import basis

    assert basis.BasisError is BasisError and issubclass(BasisError, BrdfcodecError)
    assert issubclass(BasisError, ValueError)  # callers that caught ValueError still do
    assert issubclass(BasisMismatchError, BrdfcodecError)


SHA = "ab" * 32
DETAIL = {"transform": "dct3-ycc", "step": 0.5, "dtype": "int16", "length": 100}


@pytest.mark.parametrize(("layers", "error"), [
    ({"detail": {**DETAIL, "quality": 3}}, "unsupported"),  # unknown key inside detail, as in layers and basis
    ({"detail": {k: v for k, v in DETAIL.items() if k != "transform"}}, "malformed"),  # a required key missing
    ({"detail": {**DETAIL, "transform": 5}}, "malformed"),  # the wrong JSON type
    ({"detail": {**DETAIL, "transform": "wavelet"}}, "unsupported"),  # a string this reader does not know
    ({"detail": {**DETAIL, "dtype": "int8"}}, "unsupported"),
    ({"detail": {**DETAIL, "dtype": 16}}, "malformed"),
    ({"detail": DETAIL, "mu": None}, "malformed"),
    ({"detail": DETAIL, "mu": "int4"}, "unsupported"),
    ({"detail": DETAIL, "sigma": 8}, "malformed"),
    ({"detail": DETAIL, "sigma": "log2-u4"}, "unsupported"),
])
def test_layer_keys_and_values_have_the_spec_error_classes(layers: dict, error: str) -> None:
    """Spec §4.4/§7: a missing key or a value of the wrong JSON type is malformed; an unknown key, or a string
    value this reader does not know, is unsupported."""
    from brdfcodec.format.layered_record import UnsupportedLayerError, layers_length

    with pytest.raises(ValueError) as caught:
        layers_length(layers, "record 0 (a)", 8)
    assert isinstance(caught.value, UnsupportedLayerError) == (error == "unsupported"), caught.value


# --------------------------------------------------------------------------- 4. studio requests


@pytest.fixture(scope="module")
def studio(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    pytest.importorskip("starlette", reason="the studio needs the studio extra (starlette, uvicorn)")
    pytest.importorskip("uvicorn", reason="the studio needs the studio extra (starlette, uvicorn)")
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import LatentRecord, write_bvae
    from brdfcodec.studio.browser import running_studio
    from brdfcodec.studio.catalogue import Catalogue
    from brdfcodec.studio.server import StudioServer, create_app

    library = tmp_path_factory.mktemp("studio-library") / "lib.bvae"  # its own library: any format version
    write_bvae(library, [LatentRecord(f"m{i}", np.full(8, 0.1 * i), np.ones(8)) for i in range(3)],
               BrdfDecoder().reference)
    save_dir = tmp_path_factory.mktemp("studio-saves")
    server = StudioServer(Catalogue([str(library)]), save_dir=save_dir,
                          manifold_cache=tmp_path_factory.mktemp("umap"))
    with running_studio(create_app(server)) as url:
        yield url, save_dir


def _post(url: str, data: bytes) -> tuple[int, dict]:
    import json
    import urllib.error
    import urllib.request

    req = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=120) as response:
            return response.status, json.loads(response.read() or b"{}") if "json" in response.headers.get(
                "content-type", "") else {}
    except urllib.error.HTTPError as error:
        return error.code, json.loads(error.read())


def _save_body(**changes: object) -> bytes:
    import json

    body = {"file": "s.bvae", "name": "saved", "z": [0.1] * 8, "edit": {"changed": [1]}, **changes}
    return json.dumps(body).encode()


@pytest.mark.parametrize(("route", "data", "fragment"), [
    ("decode", b'{"z": ' + b"[" * 30_000 + b"]" * 30_000 + b"}", "deeper"),  # was a RecursionError: 500
    ("decode", b'{"z": [' + b"9" * 4000 + b', 0, 0, 0, 0, 0, 0, 0]}', "beyond"),  # was an OverflowError: 500
    ("decode", b'{"z": [1e400, 0, 0, 0, 0, 0, 0, 0]}', "finite"),
    ("save", _save_body(edit={"t": float("nan")}), "finite"),
    ("save", _save_body(edit={"t": 1.0}).replace(b"1.0", b"1e400"), "finite"),
    ("save", _save_body(edit={"t": 1.0}).replace(b"1.0", b"-Infinity"), "finite"),
    ("save", _save_body(edit={"dims_from_a": [1e21]}), "finite numbers"),
    ("save", _save_body(file="ok.bvae\n"), "plain name"),  # "$" matched before the newline
    ("save", _save_body(name="saved\n"), "name"),
    ("save", _save_body(file="CON.bvae"), "reserved device name"),
    ("save", _save_body(file="nul.bvae"), "reserved device name"),
    ("save", _save_body(file="lpt1.png"), "reserved device name"),
])
def test_studio_bad_bodies_are_400_not_500(studio: tuple[str, Path], route: str, data: bytes, fragment: str) -> None:
    url, save_dir = studio
    status, body = _post(f"{url}/api/{route}", data)
    assert status == 400, body
    assert fragment in body["error"]
    assert not any(save_dir.iterdir())


def test_studio_slow_body_is_cut_off(studio: tuple[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    import socket
    import time
    from urllib.parse import urlparse

    from brdfcodec.studio import server

    monkeypatch.setattr(server, "BODY_TIMEOUT_S", 0.5)
    url, _ = studio
    parts = urlparse(url)
    with socket.create_connection((parts.hostname, parts.port), timeout=30) as sock:
        sock.sendall(b"POST /api/decode HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                     b"Content-Length: 100\r\n\r\n{\"z\": ")
        start = time.monotonic()
        answer = sock.recv(4096)
        waited = time.monotonic() - start
    assert answer.startswith(b"HTTP/1.1 408") and waited < 10, (answer[:200], waited)


def test_studio_saves_a_good_body(studio: tuple[str, Path]) -> None:
    url, save_dir = studio
    status, body = _post(f"{url}/api/save", _save_body(file="fine.bvae", edit={"t": 0.5, "dims_from_a": [1, 2]}))
    assert status == 200 and (save_dir / "fine.bvae").is_file(), body
    (save_dir / "fine.bvae").unlink()


# --------------------------------------------------------------------------- 5. flags


@pytest.mark.parametrize("budget", ["1", "9", "99999999999999999999", str(2**30 + 1)])
def test_bytes_out_of_range_is_a_usage_error_before_the_model_loads(tmp_path: Path, red_plastic_file: Path,
                                                                     budget: str, monkeypatch: pytest.MonkeyPatch,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    import brdfcodec.codec

    def no_model(*args: object, **kwargs: object) -> None:
        raise AssertionError("the model was loaded before the flags were checked")

    monkeypatch.setattr(brdfcodec.codec.BrdfEncoder, "__init__", no_model)
    output = tmp_path / "out.bvae"
    # --latent always: the floor of records with a latent (without one, from 6 B: test_basis_only.py)
    assert main(["compress", str(red_plastic_file), "-o", str(output), "--bytes", budget, "--latent", "always"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--bytes" in err[0] and "Traceback" not in err[0]
    assert not output.exists()


def test_bytes_floor_is_the_smallest_record_the_encoder_writes() -> None:
    """The floor checked up front is the one rate control enforces: a one-byte name, a compact base and one
    coefficient, for the shipped model (D = 8, float32)."""
    from brdfcodec.codec.rate import smallest_bytes_budget
    from brdfcodec.format.bvae import record_overhead

    assert smallest_bytes_budget(8, 4, basis=True) == 8 + 1 + 2 + 1 + record_overhead("a", basis_count=1)
    assert smallest_bytes_budget(8, 4, basis=False) == 64 + record_overhead("a")
    # without σ (format 2.2, what bvae compress writes unless --sigma): the base alone, μ on the fixed grid
    assert smallest_bytes_budget(8, 4, basis=True, store_sigma=False) == 8 + record_overhead("a")
    assert smallest_bytes_budget(8, 4, basis=False, store_sigma=False) == 8 + record_overhead("a")
