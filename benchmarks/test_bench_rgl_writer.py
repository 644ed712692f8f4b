"""Writing one material as an RGL .bsdf file, against writing the same table as a MERL .binary file.

Both start from a table in memory (the analytic gold preset) and write atomically; the candidate builds the
whole parameterisation (power-iteration NDF, σ, VNDF warps, RGB and luminance at the warped samples, at
the default resolution) first (issue 38 target: at most a few seconds per material).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.io.merl import MerlBRDF, write_merl


@pytest.fixture(scope="module")
def gold() -> MerlBRDF:
    return ANALYTIC_PRESETS["gold"].to_merl()


def test_rgl_write_baseline_merl(benchmark: pytest.FixtureRequest, gold: MerlBRDF, tmp_path: Path) -> None:
    benchmark.group = "rgl-write"
    benchmark.extra_info["role"] = "baseline"
    benchmark.pedantic(write_merl, args=(tmp_path / "gold.binary", gold), kwargs={"overwrite": True},
                       rounds=5, iterations=1, warmup_rounds=1)


def test_rgl_write(benchmark: pytest.FixtureRequest, gold: MerlBRDF, tmp_path: Path) -> None:
    from brdfcodec.io.rgl import read_rgl_header
    from brdfcodec.io.rgl_writer import write_rgl_bsdf

    benchmark.group = "rgl-write"
    benchmark.extra_info["role"] = "candidate"
    path = benchmark.pedantic(write_rgl_bsdf, args=(tmp_path / "gold.bsdf", gold.values),
                              kwargs={"name": "gold", "overwrite": True}, rounds=5, iterations=1, warmup_rounds=1)
    assert read_rgl_header(path).theta_i_count == 32
