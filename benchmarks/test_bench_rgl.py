"""Tabulating a real RGL .bsdf measurement on the MERL grid, against tabulating an NBRDF proxy fit.

Both evaluate one BRDF at the 1,458,000 MERL bins; the proxy's is a small
NumPy MLP, the RGL one Mitsuba's ``measured`` plugin through Dr.Jit's LLVM
backend (issue 12 target: one RGL file in ≤ 10 s on 2 cores).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from brdfcodec.datasets.nbrdf import iter_nbrdf_zip


@pytest.fixture(scope="module")
def rgl_file(nbrdf_zip: Path) -> Path:
    path = nbrdf_zip.parent / "rgl" / "paper_white_rgb.bsdf"
    if not path.is_file():
        pytest.skip(f"real RGL measurement not found at {path}")
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (extra brdfcodec[rgl])")
    from brdfcodec.runtime.mitsuba import LibLLVMNotFoundError, find_libllvm

    try:
        find_libllvm()
    except LibLLVMNotFoundError as error:
        pytest.skip(str(error))
    return path


def test_rgl_baseline_proxy_tabulation(benchmark: pytest.FixtureRequest, nbrdf_zip: Path, rgl_file: Path) -> None:
    benchmark.group = "rgl-tabulate"
    benchmark.extra_info["role"] = "baseline"
    fit = next(iter_nbrdf_zip(nbrdf_zip, ["green-acrylic"]))
    benchmark.pedantic(fit.to_merl, rounds=3, iterations=1)


def test_rgl_tabulation(benchmark: pytest.FixtureRequest, rgl_file: Path) -> None:
    from brdfcodec.io.rgl import read_rgl_bsdf

    benchmark.group = "rgl-tabulate"
    benchmark.extra_info["role"] = "candidate"
    brdf = benchmark.pedantic(read_rgl_bsdf, args=(rgl_file,), rounds=3, iterations=1, warmup_rounds=1)
    assert brdf.valid_fraction > 0.7
