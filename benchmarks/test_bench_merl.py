"""MERL file reading and writing against plain numpy I/O of the same bytes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from brdfcodec.io.merl import read_merl, write_merl


def test_read_baseline_numpy_fromfile(benchmark: pytest.FixtureRequest, merl_file: Path) -> None:
    benchmark.group = "merl-read"
    benchmark.extra_info["role"] = "baseline"
    data = benchmark(np.fromfile, merl_file, dtype="<f8", offset=12)
    assert data.size == 3 * 90 * 90 * 180


def test_read_merl(benchmark: pytest.FixtureRequest, merl_file: Path) -> None:
    benchmark.group = "merl-read"
    benchmark.extra_info["role"] = "candidate"
    brdf = benchmark(read_merl, merl_file)
    assert brdf.values.shape == (3, 90, 90, 180)


def test_write_baseline_numpy_tofile(benchmark: pytest.FixtureRequest, merl_file: Path, tmp_path: Path) -> None:
    benchmark.group = "merl-write"
    benchmark.extra_info["role"] = "baseline"
    values = read_merl(merl_file).values
    benchmark(values.tofile, tmp_path / "raw.bin")


def test_write_merl(benchmark: pytest.FixtureRequest, merl_file: Path, tmp_path: Path) -> None:
    benchmark.group = "merl-write"
    benchmark.extra_info["role"] = "candidate"
    values = read_merl(merl_file).values
    benchmark(write_merl, tmp_path / "out.binary", values, overwrite=True)
