"""``decode_many`` against the network alone (issue 51, 2): the host path after the network costs little.

32 random latents, CPU, one process: ``BrdfDecoder.decode_many`` (full tables, below-horizon entries −1, every
table consumed) against the decoder network alone on the same latents, in batches of the same size, on the same
torch threads (``codec_threads``). Paired: each round times both, alternating, so that a shared machine's drift
falls on both; the ratio checked is the median of the per-round ratios (target in ``conftest.TARGETS``,
"decode-many-32").
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import torch

from brdfcodec.codec import BrdfDecoder
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.runtime.threads import codec_threads

_COUNT = 32
_BATCH = 16
_ROUNDS = 5


def test_decode_many_against_the_network_alone(benchmark) -> None:
    benchmark.group = "decode-many-32"
    benchmark.extra_info["role"] = "candidate"
    decoder = BrdfDecoder()
    codes = np.random.default_rng(0).standard_normal((_COUNT, decoder.latent_dim)).astype(np.float32)
    records = [LatentRecord(f"m{i}", codes[i], np.ones(decoder.latent_dim, np.float32)) for i in range(_COUNT)]

    def network_alone() -> None:
        with codec_threads(), torch.inference_mode():
            for start in range(0, _COUNT, _BATCH):
                decoder.network(torch.from_numpy(codes[start : start + _BATCH])).numpy()

    def decode_many() -> None:
        for table in decoder.decode_many(records, batch_size=_BATCH):
            assert table.shape == (3, 90, 90, 180)

    network_alone()  # warm-up: first-call allocations, cached plans and masks
    decode_many()
    baseline: list[float] = []
    ratios: list[float] = []

    def time_the_network() -> None:  # pedantic's setup: untimed by the benchmark, timed here, before each round
        start = time.perf_counter()
        network_alone()
        baseline.append(time.perf_counter() - start)

    def timed_decode() -> None:
        start = time.perf_counter()
        decode_many()
        ratios.append((time.perf_counter() - start) / baseline[-1])

    benchmark.pedantic(timed_decode, setup=time_the_network, rounds=_ROUNDS, iterations=1)
    benchmark.extra_info["paired_baseline_s"] = statistics.median(baseline)
    benchmark.extra_info["paired_ratio"] = statistics.median(ratios)
    benchmark.extra_info["summary"] = (f"decode_many / network alone, {_COUNT} latents: per-round ratios "
                                       + ", ".join(f"{r:.2f}" for r in ratios))
