"""The ``bvae`` command line: info, analytic, dataset build, and its error handling."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.cli import main
from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.io.merl import read_merl


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.mark.slow
def test_info_describes_a_merl_file(capsys: pytest.CaptureFixture[str], red_plastic_file: Path) -> None:
    code, out, err = run(capsys, "info", str(red_plastic_file))
    assert code == 0, err
    assert "90 x 90 x 180" in out and "34,992,012 bytes" in out
    assert "genuine MERL    no" in out
    assert "valid entries   76.23 %" in out
    for channel in ("red", "green", "blue"):
        assert channel in out


def test_info_json(capsys: pytest.CaptureFixture[str], red_plastic_file: Path) -> None:
    code, out, _ = run(capsys, "info", "--json", str(red_plastic_file))
    assert code == 0
    summary = json.loads(out)
    assert summary["sha256"] == read_merl(red_plastic_file).sha256
    assert summary["genuine_merl"] is None
    assert summary["reflectance_per_sr"]["red"]["max"] > summary["reflectance_per_sr"]["green"]["max"]


@pytest.mark.slow  # > 10 s on 2 cores
def test_analytic_then_info_then_dataset(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    out_file = tmp_path / "gold.binary"
    code, out, err = run(capsys, "analytic", "gold", "-o", str(out_file))
    assert code == 0, err
    np.testing.assert_array_equal(read_merl(out_file).values, ANALYTIC_PRESETS["gold"].to_merl().values)
    code, _, err = run(capsys, "analytic", "gold", "-o", str(out_file))
    assert code == 1 and "already exists" in err and "--force" in err
    code, _, err = run(capsys, "analytic", "-o", str(tmp_path / "c.binary"), "--diffuse", "0.1,0.2,0.3",
                       "--roughness", "0.3")
    assert code == 0, err
    custom = read_merl(tmp_path / "c.binary").reflectance()
    np.testing.assert_allclose(custom[:, 60, 10, 90], np.array([0.1, 0.2, 0.3]) / np.pi, rtol=0.1)  # diffuse
    ds = tmp_path / "a.h5"
    code, out, err = run(capsys, "dataset", "build", "--analytic", "--materials", "gold,chrome", "--random", "1",
                         "-o", str(ds), "--quiet")
    assert code == 0, err
    assert "3 materials (analytic)" in out
    code, out, _ = run(capsys, "info", str(ds))
    assert code == 0 and "brdfcodec dataset (analytic)" in out and "3 (" in out
    # --random alone: random materials without the presets (it used to be ignored without --analytic)
    code, out, err = run(capsys, "dataset", "build", "--random", "2", "-o", str(tmp_path / "r.h5"), "--quiet",
                         "--no-tables")
    assert code == 0, err
    assert "2 materials (analytic)" in out


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (struct.pack("<3i", 90, 90, 180) + b"\0" * 100, "truncated"),
        (b"GIF89a" + b"\0" * 50, "not a MERL"),
        (b"abc", "neither a MERL"),
        (struct.pack("<3i", 90, 90, 180) + struct.pack("<d", np.nan) * (3 * 90 * 90 * 180), "NaN"),
        (struct.pack("<3i", 90, 90, 180) + b"\0" * (24 * 90 * 90 * 180 + 8), "trailing bytes"),
    ],
    ids=["truncated", "gif", "tiny", "nan", "trailing"],
)
def test_info_rejects_bad_files_cleanly(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, content: bytes, expected: str
) -> None:
    path = tmp_path / "bad.binary"
    path.write_bytes(content)
    code, out, err = run(capsys, "info", str(path))
    assert code == 1
    assert str(path) in err and expected in err
    assert "Traceback" not in err and out == ""


def test_info_missing_file_and_directory(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _, err = run(capsys, "info", str(tmp_path / "nope.binary"))
    assert code == 1 and "nope.binary" in err and "No such file" in err
    code, _, err = run(capsys, "info", str(tmp_path))
    assert code == 1 and "is a directory" in err


def test_dataset_build_errors(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _, err = run(capsys, "dataset", "build", "--merl", str(tmp_path), "-o", str(tmp_path / "x.h5"))
    assert code == 1 and "no MERL .binary files" in err
    code, _, err = run(capsys, "dataset", "build", "--analytic", "--materials", "unobtainium",
                       "-o", str(tmp_path / "x.h5"))
    assert code == 1 and "unknown analytic preset" in err
    assert not (tmp_path / "x.h5").exists()


def test_usage_errors_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(capsys, "frobnicate")[0] == 2
    assert run(capsys, "dataset", "build", "-o", "x.h5")[0] == 2  # no source given
    assert run(capsys, "--version")[0] == 0


def test_entry_point_runs_without_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "bad.binary"
    bad.write_bytes(b"\x00" * 1000)
    env = {**os.environ, "BVAE_DEBUG": ""}
    result = subprocess.run([sys.executable, "-m", "brdfcodec", "info", str(bad)], capture_output=True,
                            text=True, env=env, timeout=120)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr and "bad.binary" in result.stderr


@pytest.mark.shared
@pytest.mark.slow
def test_dataset_build_from_proxy(capsys: pytest.CaptureFixture[str], nbrdf_zip: Path, tmp_path: Path) -> None:
    out = tmp_path / "proxy.h5"
    code, stdout, err = run(capsys, "dataset", "build", "--nbrdf-zip", str(nbrdf_zip), "--materials",
                            "green-acrylic,chrome", "-o", str(out), "--no-tables", "--quiet")
    assert code == 0, err
    assert "2 materials (nbrdf-proxy)" in stdout
    code, stdout, _ = run(capsys, "info", str(out))
    assert "NOT measured MERL" in stdout
