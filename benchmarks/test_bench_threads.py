"""The library's default threads beside CPU-bound processes (issue 39, 1).

A renderer that imports brdfcodec while its own threads are busy: a 16 KB
encode (effort 1, rate control) through ``bc.BrdfEncoder`` with the
library's default thread setting, beside one CPU-bound process per core,
against the best explicit setting (``bc.set_num_threads(n)`` for every n
from 1 to the number of cores; n = the number of cores is torch's own
default) timed in the same rounds.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator

import numpy as np
import pytest

import brdfcodec as bc
from brdfcodec.datasets.analytic import ANALYTIC_PRESETS

_ROUNDS = 3


@pytest.fixture
def busy_cores() -> Iterator[int]:
    """One CPU-bound process per core for the duration of the benchmark; stopped (by their ids) after it."""
    cores = os.cpu_count() or 1
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(cores)]
    time.sleep(1.0)
    try:
        yield cores
    finally:
        for process in spinners:
            process.kill()
        for process in spinners:
            process.wait()


def test_encode_16kb_beside_busy_cores(benchmark, busy_cores: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Paired: each round times the encode at every explicit thread count (the setup), then at the default."""
    monkeypatch.delenv("BVAE_NUM_THREADS", raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    benchmark.group = "encode-16KB-busy"
    benchmark.extra_info["role"] = "candidate"
    table = ANALYTIC_PRESETS["gold"].to_merl()
    encoder = bc.BrdfEncoder(effort=1, bytes=16384)
    encoder.encode(table)  # loads the decoder and the shared basis once
    counts = list(range(1, busy_cores + 1))
    explicit: dict[int, list[float]] = {n: [] for n in counts}

    def explicit_settings_timed() -> None:
        for n in counts:
            bc.set_num_threads(n)
            start = time.perf_counter()
            encoder.encode(table)
            explicit[n].append(time.perf_counter() - start)
        bc.set_num_threads(None)  # the candidate: the library's default

    try:
        record = benchmark.pedantic(encoder.encode, args=(table,), setup=explicit_settings_timed,
                                    rounds=_ROUNDS, iterations=1)
    finally:
        bc.set_num_threads(None)
    assert record.meta["rate"]["bytes_budget"] == 16384
    if benchmark.disabled:
        return
    default = np.asarray(benchmark.stats.stats.data, dtype=float)
    per_count = {n: np.asarray(seconds[-_ROUNDS:], dtype=float) for n, seconds in explicit.items()}
    best = np.min(np.stack(list(per_count.values())), axis=0)  # per round, the best explicit setting
    benchmark.extra_info["paired_baseline_s"] = float(np.median(best))
    benchmark.extra_info["paired_ratio"] = float(np.median(default / best))
    benchmark.extra_info["default_threads"] = bc.get_num_threads()
    benchmark.extra_info["summary"] = (
        f"default ({bc.get_num_threads()} thread(s)) median {np.median(default):.2f} s; "
        + ", ".join(f"{n} thread(s) {np.median(t):.2f} s" for n, t in per_count.items())
        + f"; beside {busy_cores} CPU-bound process(es)"
    )
