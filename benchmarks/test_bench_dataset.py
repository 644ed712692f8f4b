"""Building the NBRDF proxy dataset against tabulating the same fits (the work no builder can skip)."""

from __future__ import annotations

from pathlib import Path

import pytest

from brdfcodec.datasets.hdf5 import build_dataset
from brdfcodec.datasets.nbrdf import iter_nbrdf_zip
from brdfcodec.datasets.sources import nbrdf_zip_sources

MATERIALS = ["green-acrylic", "chrome"]


def test_proxy_build_baseline_tabulation_only(benchmark: pytest.FixtureRequest, nbrdf_zip: Path) -> None:
    """The irreducible part: evaluating the fits on the MERL grid, nothing mapped, stored or compressed."""
    benchmark.group = "proxy-build"
    benchmark.extra_info["role"] = "baseline"
    fits = list(iter_nbrdf_zip(nbrdf_zip, MATERIALS))

    def tabulate() -> None:
        for fit in fits:
            fit.to_merl()

    benchmark.pedantic(tabulate, rounds=3, iterations=1)


def test_proxy_build(benchmark: pytest.FixtureRequest, nbrdf_zip: Path, tmp_path: Path) -> None:
    benchmark.group = "proxy-build"
    benchmark.extra_info["role"] = "candidate"
    sources = nbrdf_zip_sources(nbrdf_zip, MATERIALS)
    out = tmp_path / "proxy.h5"

    def build() -> None:
        build_dataset(out, sources, source_kind="nbrdf-proxy", description="bench", overwrite=True, progress=False)

    benchmark.pedantic(build, rounds=3, iterations=1)
    assert out.stat().st_size > 0
