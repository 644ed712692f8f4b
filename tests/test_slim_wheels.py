"""The device runs' wheel slimmer (``benchmarks/device/slim_wheels.py``): what it keeps, and a RECORD that matches."""

from __future__ import annotations

import base64
import hashlib
import zipfile
from pathlib import Path
from types import ModuleType

import pytest
from script_loading import load_script

ROOT = Path(__file__).resolve().parents[1]


def _slim() -> ModuleType:
    return load_script(ROOT / "benchmarks" / "device" / "slim_wheels.py")


def _wheel(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as wheel:
        for name, data in members.items():
            wheel.writestr(name, data)
        wheel.writestr("mitsuba-3.9.1.dist-info/RECORD", "stale,,\n")
    return path


def test_mitsuba_keeps_one_variant_the_scene_plugins_and_a_true_record(tmp_path: Path) -> None:
    slim = _slim()
    members = {
        "mitsuba/__init__.py": b"# init", "mitsuba/libmitsuba.so": b"core", "mitsuba/libembree3.so": b"rt",
        "mitsuba/cuda_ad_rgb.cpython-312-x86_64-linux-gnu.so": b"cuda", "mitsuba/data/ior/gold.eta.spd": b"ior",
        "mitsuba/llvm_ad_rgb.cpython-312-x86_64-linux-gnu.so": b"llvm",
        "mitsuba/scalar_spectral.cpython-312-x86_64-linux-gnu.so": b"scalar",
        "mitsuba/plugins/path.so": b"path", "mitsuba/plugins/merge.so": b"merge", "mitsuba/plugins/volpath.so": b"v",
        "mitsuba/data/srgb.coeff": b"coeff", "mitsuba/__init__.pyi": b"stub", "mitsuba/include/mitsuba.h": b"h",
        "mitsuba-3.9.1.dist-info/METADATA": b"Name: mitsuba",
    }
    source, target = _wheel(tmp_path / "in.whl", members), tmp_path / "out.whl"
    kept, dropped = slim.rewrite_wheel(source, target, slim.keep_mitsuba("cuda_ad_rgb"))
    with zipfile.ZipFile(target) as wheel:
        names = set(wheel.namelist())
        assert names == {"mitsuba/__init__.py", "mitsuba/libmitsuba.so", "mitsuba/libembree3.so",
                         "mitsuba/cuda_ad_rgb.cpython-312-x86_64-linux-gnu.so", "mitsuba/data/ior/gold.eta.spd",
                         "mitsuba/plugins/path.so", "mitsuba/plugins/merge.so", "mitsuba-3.9.1.dist-info/METADATA",
                         "mitsuba-3.9.1.dist-info/RECORD"}
        assert (kept, dropped) == (len(names) - 1, len(members) - (len(names) - 1))
        record = wheel.read("mitsuba-3.9.1.dist-info/RECORD").decode().splitlines()
        assert len(record) == len(names) and record[-1] == "mitsuba-3.9.1.dist-info/RECORD,,"
        for line in record[:-1]:
            name, digest, size = line.split(",")
            data = wheel.read(name)
            assert digest == "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
            assert int(size) == len(data) == len(members[name])


def test_colour_science_and_zstandard_drop_only_what_the_run_does_not_import() -> None:
    slim = _slim()
    assert slim.keep_colour_science("colour/__init__.py") and slim.keep_colour_science("colour/models/rgb.py")
    assert not slim.keep_colour_science("colour/models/tests/test_rgb.py")
    assert not slim.keep_colour_science("colour/x/htmlcov/index.html")
    assert not slim.keep_colour_science("colour/examples/plotting.py")
    assert slim.keep_zstandard("zstandard/__init__.py") and slim.keep_zstandard("zstandard/backend_c.cpython-312.so")
    assert not slim.keep_zstandard("zstandard/_cffi.cpython-312-x86_64-linux-gnu.so")
    assert not slim.keep_zstandard("zstandard/backend_cffi.py")


def test_a_zip_without_a_record_or_a_target_that_is_the_source_is_refused_and_nothing_is_left(tmp_path: Path) -> None:
    slim = _slim()
    plain = tmp_path / "plain.zip"
    with zipfile.ZipFile(plain, "w") as archive:
        archive.writestr("a.txt", b"a")
    target = tmp_path / "out.whl"
    with pytest.raises(ValueError, match="not a wheel"):
        slim.rewrite_wheel(plain, target, lambda name: True)
    source = _wheel(tmp_path / "in.whl", {"mitsuba/__init__.py": b"# init"})
    before = source.read_bytes()
    with pytest.raises(ValueError, match="overwrite its source"):
        slim.rewrite_wheel(source, tmp_path / "." / "in.whl", lambda name: True)
    assert source.read_bytes() == before

    def failing(name: str) -> bool:
        raise RuntimeError("a keep rule that fails half way")

    with pytest.raises(RuntimeError, match="half way"):
        slim.rewrite_wheel(source, target, failing)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.whl", "plain.zip"]  # no target, no .part
