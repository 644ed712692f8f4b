"""The benchmark suite's ratio report (``benchmarks/conftest.py``): plain and paired groups."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
from script_loading import load_script

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench_conftest():
    return load_script(REPO_ROOT / "benchmarks" / "conftest.py", "brdfcodec_bench_conftest")


def _bench(group: str, role: str, median: float, **extra: float) -> SimpleNamespace:
    return SimpleNamespace(group=group, extra_info={"role": role, **extra},
                           stats=SimpleNamespace(rounds=10, median=median))


def _config(*benches: SimpleNamespace) -> SimpleNamespace:
    return SimpleNamespace(_benchmarksession=SimpleNamespace(disabled=False, benchmarks=list(benches)))


def test_a_plain_group_divides_the_two_medians(bench_conftest) -> None:
    report = bench_conftest._ratios(_config(_bench("decode-full", "baseline", 0.002),
                                            _bench("decode-full", "candidate", 0.010)))
    row = report["decode-full"]
    assert row["ratio"] == pytest.approx(5.0)
    assert not row["paired"]
    assert row["target"] == bench_conftest.TARGETS["decode-full"]


def test_a_paired_group_reports_the_median_of_its_rounds_ratios(bench_conftest) -> None:
    # The quotient of the medians (0.018 / 0.010 = 1.8) is not what a paired group checks.
    candidate = _bench("decode-layered", "candidate", 0.018, paired_baseline_s=0.010, paired_ratio=1.4)
    row = bench_conftest._ratios(_config(candidate))["decode-layered"]
    assert row["paired"]
    assert row["ratio"] == pytest.approx(1.4)
    assert row["baseline_s"] == pytest.approx(0.010)
    assert row["candidate_s"] == pytest.approx(0.018)


def test_a_group_without_a_baseline_is_left_out(bench_conftest) -> None:
    assert bench_conftest._ratios(_config(_bench("decode-layered", "candidate", 0.018))) == {}


def test_a_disabled_session_reports_nothing(bench_conftest) -> None:
    config = _config(_bench("decode-full", "baseline", 0.002), _bench("decode-full", "candidate", 0.010))
    config._benchmarksession.disabled = True
    assert bench_conftest._ratios(config) == {}
