"""Writing and reading a library at the record limit takes linear time (issue 36: the check that the old
quadratic duplicate-name test, 89 s at 65,536 records, stays gone).

Paired: each round times a library of 8,192 records (the baseline, in the setup) and one of 65,536 (the
candidate): 8× the records, so the ratio is about 8 for linear work and 64 for quadratic.
"""

from __future__ import annotations

import time

import numpy as np

from brdfcodec.format.bvae import MAX_RECORDS, DecoderReference, LatentRecord, encode_bvae, parse_bvae

_DECODER = DecoderReference("ab" * 32, "bench-decoder")
_ROUNDS = 3


def _records(count: int) -> list[LatentRecord]:
    return [LatentRecord(f"m{i}", np.zeros(8), np.ones(8), {"relae": {"mapped": 0.1, "linear": 0.2}})
            for i in range(count)]


def _round_trip(records: list[LatentRecord]) -> int:
    return len(parse_bvae(encode_bvae(records, _DECODER)).records)


def test_record_limit_round_trip_is_linear(benchmark) -> None:
    benchmark.group = "record-limit-round-trip"
    benchmark.extra_info["role"] = "candidate"
    small, large = _records(MAX_RECORDS // 8), _records(MAX_RECORDS)
    baseline: list[float] = []

    def time_the_baseline() -> None:
        start = time.perf_counter()
        _round_trip(small)
        baseline.append(time.perf_counter() - start)

    count = benchmark.pedantic(_round_trip, args=(large,), setup=time_the_baseline, rounds=_ROUNDS, iterations=1)
    assert count == MAX_RECORDS
    if benchmark.disabled:
        return
    candidate = np.asarray(benchmark.stats.stats.data, dtype=float)
    benchmark.extra_info["paired_baseline_s"] = float(np.median(baseline))
    benchmark.extra_info["paired_ratio"] = float(np.median(candidate / np.asarray(baseline)))
