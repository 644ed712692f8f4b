"""The benchmark suite still runs (each benchmark once, untimed), so it cannot rot unnoticed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_benchmarks_run_once(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "pytest", str(REPO_ROOT / "benchmarks"), "--benchmark-disable", "-q",
         "-p", "no:cacheprovider", f"--basetemp={tmp_path / 'tmp'}"],
        # 900 s: the suite, run once, took more than 600 s on a 2-core machine busy with other runs (2026-12-06)
        capture_output=True, text=True, cwd=REPO_ROOT, timeout=900,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert " passed" in result.stdout
