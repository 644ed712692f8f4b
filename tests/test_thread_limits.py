"""Thread counts from the environment and the BLAS scan (issue 51 item 2; red-team R3-12).

A huge ``BVAE_NUM_THREADS`` or ``OMP_NUM_THREADS`` is limited to the cores the process may use, with a message
naming the variable, instead of ending the process in libgomp; the BLAS libraries are scanned once, not on every
decode.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from brdfcodec.cli.main import configure_threads
from brdfcodec.runtime import threads
from brdfcodec.runtime.threads import (
    ThreadCountWarning,
    available_cores,
    codec_threads,
    environment_thread_count,
    get_num_threads,
    set_num_threads,
)


@pytest.mark.parametrize("name", ["BVAE_NUM_THREADS", "OMP_NUM_THREADS"])
@pytest.mark.parametrize("value", ["999999999", "100000", "4096"])
def test_a_huge_count_is_limited_to_the_cores_and_named(name: str, value: str) -> None:
    with pytest.warns(ThreadCountWarning, match=name):
        assert environment_thread_count({name: value}) == available_cores()
    with pytest.warns(ThreadCountWarning, match=name):
        assert get_num_threads({name: value}) == available_cores()


def test_counts_within_the_cores_and_bad_values_are_as_before() -> None:
    assert environment_thread_count({"BVAE_NUM_THREADS": "1", "OMP_NUM_THREADS": "999"}) == 1
    assert environment_thread_count({"BVAE_NUM_THREADS": "x", "OMP_NUM_THREADS": "1"}) == 1
    assert environment_thread_count({"BVAE_NUM_THREADS": "0"}) is None
    assert environment_thread_count({}) is None


def test_set_num_threads_is_limited_too() -> None:
    try:
        with pytest.warns(ThreadCountWarning, match="set_num_threads"):
            set_num_threads(10**9)
        assert get_num_threads() == available_cores()
    finally:
        set_num_threads(None)


def test_the_cli_exports_the_limited_count(capsys: pytest.CaptureFixture[str]) -> None:
    env = {"BVAE_NUM_THREADS": "999999999"}
    assert configure_threads(env) == available_cores()
    assert env["OMP_NUM_THREADS"] == str(available_cores())
    err = capsys.readouterr().err
    assert "BVAE_NUM_THREADS=999999999" in err and err.startswith("bvae: warning:")


@pytest.mark.parametrize("name", ["BVAE_NUM_THREADS", "OMP_NUM_THREADS"])
@pytest.mark.slow
def test_bvae_runs_with_a_huge_count(name: str, tmp_path) -> None:
    """R3-12's repro, end to end: the process decodes and says why it used fewer threads (no libgomp abort)."""
    from brdfcodec.examples import example_library

    env = {**os.environ, name: "999999999"}
    out = tmp_path / "x.npy"
    run = subprocess.run([sys.executable, "-m", "brdfcodec", "decompress", str(example_library()), "--material",
                          "chrome", "--phi-d", "0", "-o", str(out)], env=env, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    assert f"{name}=999999999" in run.stderr and "libgomp" not in run.stderr
    assert np.load(out).shape == (3, 90, 90, 1)


def test_the_blas_libraries_are_scanned_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """The scan (threadpoolctl's walk over every loaded library) is made again only after an import."""
    import threadpoolctl

    scans = []
    real = threadpoolctl.ThreadpoolController

    def counting() -> object:
        scans.append(1)
        return real()

    monkeypatch.setattr(threadpoolctl, "ThreadpoolController", counting)
    monkeypatch.setattr(threads, "_scanned", None)
    for _ in range(5):
        with codec_threads():
            pass
    assert len(scans) == 1
    monkeypatch.setitem(sys.modules, "brdfcodec_test_new_module", sys)  # an import happened
    with codec_threads():
        pass
    assert len(scans) == 2
