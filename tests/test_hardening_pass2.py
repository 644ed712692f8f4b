"""Regression tests of the second hardening pass (issue 37): each defect the red-team found, rebuilt here.

The reproductions in ``../shared/redteam-2/`` are not needed: every crafted file is generated in the test
(the ``.bvae`` ones with the test's own tiny model, the ``.bsdf`` ones from a small synthetic tensor file).
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from tensor_files import field_shape_position, small_rgl_fields, tensor_file

from brdfcodec.cli import main
from brdfcodec.errors import BrdfcodecError, SourceFormatError
from brdfcodec.rgl import check_supported, read_rgl_header

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

    from brdfcodec import rgl

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
    from brdfcodec.mitsuba_runtime import LibLLVMNotFoundError, find_libllvm
    from brdfcodec.rgl import read_rgl_bsdf

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
