"""``decode_many`` and ``decode_many_tensor`` against the network alone (issue 51, 1-2): the work after the network
costs little.

32 random latents, CPU, one process: ``BrdfDecoder.decode_many`` (full tables, below-horizon entries −1, every
table consumed), and ``BrdfDecoder.decode_many_tensor`` (the same tables as one torch tensor, computed with torch
on the decoder's device), each against the decoder network alone on the same latents, in the batches the decodes
give it (:meth:`BrdfDecoder.network_batch`: 2 on the CPU, whichever ``batch_size`` is asked; "decode-network-batch"
checks that they are not slower than batches of 16), on the same torch threads (``codec_threads``). Paired: each
round times both, alternating, so that a shared machine's drift falls on both; the ratio checked is the median of
the per-round ratios (targets in ``conftest.TARGETS``, "decode-many-32", "decode-many-tensor-32" and
"decode-many-tensor-out-32", the last decoding into one tensor reused from round to round, as a renderer that
decodes batch after batch would).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np
import torch

from brdfcodec.codec import BrdfDecoder
from brdfcodec.codec.device_decode import table_from_mapped_host
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.runtime.threads import codec_threads

_COUNT = 32
_BATCH = 16
_ROUNDS = 5


def _paired_against_the_network(benchmark, group: str, label: str,  # noqa: ANN001 - pytest-benchmark's fixture
                                candidate: Callable[[BrdfDecoder, np.ndarray, list[LatentRecord]], None]) -> None:
    benchmark.group = group
    benchmark.extra_info["role"] = "candidate"
    decoder = BrdfDecoder()
    codes = np.random.default_rng(0).standard_normal((_COUNT, decoder.latent_dim)).astype(np.float32)
    records = [LatentRecord(f"m{i}", codes[i], np.ones(decoder.latent_dim, np.float32)) for i in range(_COUNT)]

    step = decoder.network_batch(_BATCH)  # the network's own batches in the decodes (2 on the CPU)

    def network_alone() -> None:
        with codec_threads(), torch.inference_mode():
            for start in range(0, _COUNT, step):
                decoder.network(torch.from_numpy(codes[start : start + step])).numpy()

    def decode() -> None:
        candidate(decoder, codes, records)

    network_alone()  # warm-up: first-call allocations, cached plans and masks
    decode()
    baseline: list[float] = []
    ratios: list[float] = []

    def time_the_network() -> None:  # pedantic's setup: untimed by the benchmark, timed here, before each round
        start = time.perf_counter()
        network_alone()
        baseline.append(time.perf_counter() - start)

    def timed_decode() -> None:
        start = time.perf_counter()
        decode()
        ratios.append((time.perf_counter() - start) / baseline[-1])

    benchmark.pedantic(timed_decode, setup=time_the_network, rounds=_ROUNDS, iterations=1)
    benchmark.extra_info["paired_baseline_s"] = statistics.median(baseline)
    benchmark.extra_info["paired_ratio"] = statistics.median(ratios)
    benchmark.extra_info["summary"] = (f"{label} / network alone, {_COUNT} latents: per-round ratios "
                                       + ", ".join(f"{r:.2f}" for r in ratios))


def test_decode_many_against_the_network_alone(benchmark) -> None:  # noqa: ANN001
    def decode_many(decoder: BrdfDecoder, codes: np.ndarray, records: list[LatentRecord]) -> None:
        for table in decoder.decode_many(records, batch_size=_BATCH):
            assert table.shape == (3, 90, 90, 180)

    _paired_against_the_network(benchmark, "decode-many-32", "decode_many", decode_many)


def test_decode_many_tensor_against_the_network_alone(benchmark) -> None:  # noqa: ANN001
    def decode_many_tensor(decoder: BrdfDecoder, codes: np.ndarray, records: list[LatentRecord]) -> None:
        tables = decoder.decode_many_tensor(records, batch_size=_BATCH)
        assert tables.shape == (_COUNT, 3, 90, 90, 180)

    _paired_against_the_network(benchmark, "decode-many-tensor-32", "decode_many_tensor", decode_many_tensor)


def test_decode_many_tensor_into_a_reused_out_against_the_network_alone(benchmark) -> None:  # noqa: ANN001
    out = torch.empty((_COUNT, 3, 90, 90, 180))  # a renderer's buffer, decoded into batch after batch

    def decode_many_tensor_into_out(decoder: BrdfDecoder, codes: np.ndarray, records: list[LatentRecord]) -> None:
        assert decoder.decode_many_tensor(records, batch_size=_BATCH, out=out) is out

    _paired_against_the_network(benchmark, "decode-many-tensor-out-32", "decode_many_tensor(out=)",
                                decode_many_tensor_into_out)


def test_the_host_passes_alone_against_the_network_alone(benchmark) -> None:  # noqa: ANN001
    """What ``decode_many`` adds to the network, alone: the host passes after it (float64 arguments and
    exponentials at the kept slices, the stepping through each gap, the mask: ``table_from_mapped_host``,
    compiled, as ``decode_many`` runs it) on the network's own outputs, computed once before, each table into a
    reused buffer. "decode-many-32"'s 1.5 leaves them 0.5 of the network's time; this is how much they take."""
    decoder = BrdfDecoder()
    codes = np.random.default_rng(0).standard_normal((_COUNT, decoder.latent_dim)).astype(np.float32)
    mapped = decoder.decode_mapped(codes, batch_size=_BATCH)
    table = np.empty((3, 90, 90, 180), dtype=np.float32)

    def host_passes(decoder: BrdfDecoder, codes: np.ndarray, records: list[LatentRecord]) -> None:
        with codec_threads():
            for slices in mapped:
                assert table_from_mapped_host(slices, masked="unmeasured", out=table, compiled=True) is table

    _paired_against_the_network(benchmark, "decode-host-passes-32", "host passes after the network", host_passes)


def test_evaluate_tensor_at_directions_against_the_network_alone(benchmark) -> None:  # noqa: ANN001
    rng = np.random.default_rng(1)
    wi, wo = rng.standard_normal((2, 4096, 3))  # a renderer's 4,096 direction pairs per material, no tables
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])

    def evaluate_tensor(decoder: BrdfDecoder, codes: np.ndarray, records: list[LatentRecord]) -> None:
        assert decoder.evaluate_tensor(records, wi, wo, batch_size=_BATCH).shape == (_COUNT, 4096, 3)

    _paired_against_the_network(benchmark, "evaluate-tensor-32x4096", "evaluate_tensor (4,096 pairs)",
                                evaluate_tensor)


def test_the_network_in_the_decoders_cpu_batches_against_batches_of_sixteen(benchmark) -> None:  # noqa: ANN001
    """The network on 32 latents in :meth:`BrdfDecoder.network_batch`'s batches (2 on the CPU) against batches of
    16, paired: the smaller batches' buffers are not returned to the system and faulted in again on every call."""
    benchmark.group = "decode-network-batch"
    benchmark.extra_info["role"] = "candidate"
    decoder = BrdfDecoder()
    codes = np.random.default_rng(0).standard_normal((_COUNT, decoder.latent_dim)).astype(np.float32)

    def network(step: int) -> None:
        with codec_threads(), torch.inference_mode():
            for start in range(0, _COUNT, step):
                decoder.network(torch.from_numpy(codes[start : start + step])).numpy()

    small = decoder.network_batch(_BATCH)
    network(_BATCH)
    network(small)
    baseline: list[float] = []
    ratios: list[float] = []

    def time_sixteen() -> None:
        start = time.perf_counter()
        network(_BATCH)
        baseline.append(time.perf_counter() - start)

    def timed_small() -> None:
        start = time.perf_counter()
        network(small)
        ratios.append((time.perf_counter() - start) / baseline[-1])

    benchmark.pedantic(timed_small, setup=time_sixteen, rounds=_ROUNDS, iterations=1)
    benchmark.extra_info["paired_baseline_s"] = statistics.median(baseline)
    benchmark.extra_info["paired_ratio"] = statistics.median(ratios)
    benchmark.extra_info["summary"] = (f"network in batches of {small} / of {_BATCH}, {_COUNT} latents: per-round "
                                       "ratios " + ", ".join(f"{r:.2f}" for r in ratios))
