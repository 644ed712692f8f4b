"""Codec speed: full-table and one-slice decode, encode from a MERL file, batch decode (shipped default model)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.io.merl import read_merl


@pytest.fixture(scope="module")
def decoder() -> BrdfDecoder:
    return BrdfDecoder()


@pytest.fixture(scope="module")
def record() -> LatentRecord:
    return LatentRecord("bench", np.linspace(-1, 1, 8), np.full(8, 0.1))


def test_full_table_baseline_numpy_copy(benchmark, decoder: BrdfDecoder, record: LatentRecord) -> None:
    """Writing the same number of bytes (a float32 table, 17.5 MB) with numpy."""
    benchmark.group = "decode-full"
    benchmark.extra_info["role"] = "baseline"
    table = decoder.decode(record)
    out = benchmark(np.copy, table)
    assert out.nbytes == 3 * 90 * 90 * 180 * 4


def test_full_table_decode(benchmark, decoder: BrdfDecoder, record: LatentRecord) -> None:
    """Decoder, interpolation to 180 slices, inverse mapping, mask: one full table."""
    benchmark.group = "decode-full"
    benchmark.extra_info["role"] = "candidate"
    table = benchmark(decoder.decode, record)
    assert table.shape == (3, 90, 90, 180)


def test_slice_baseline_full_decode(benchmark, decoder: BrdfDecoder, record: LatentRecord) -> None:
    benchmark.group = "decode-slice"
    benchmark.extra_info["role"] = "baseline"
    benchmark(decoder.decode, record)


def test_slice_decode(benchmark, decoder: BrdfDecoder, record: LatentRecord) -> None:
    """One φd bin (between two kept slices): only 6 of 63 channels are computed."""
    benchmark.group = "decode-slice"
    benchmark.extra_info["role"] = "candidate"
    table = benchmark(decoder.decode, record, phi_d_bins=[85])
    assert table.shape == (3, 90, 90, 1)


def test_encode_baseline_read(benchmark, merl_file: Path) -> None:
    benchmark.group = "encode"
    benchmark.extra_info["role"] = "baseline"
    benchmark(read_merl, merl_file)


def test_encode_from_merl_file(benchmark, merl_file: Path) -> None:
    """Read, map, select slices, run the encoder (effort 0: the network alone)."""
    encoder = BrdfEncoder(effort=0)
    benchmark.group = "encode"
    benchmark.extra_info["role"] = "candidate"
    record = benchmark(lambda: encoder.encode(read_merl(merl_file)))
    assert record.mu.shape == (8,)


_BATCH = 16


def test_batch_baseline_one_at_a_time(benchmark, decoder: BrdfDecoder) -> None:
    records = [LatentRecord(f"m{i}", np.full(8, i / _BATCH), np.ones(8)) for i in range(_BATCH)]
    benchmark.group = "decode-batch16"
    benchmark.extra_info["role"] = "baseline"
    benchmark.pedantic(lambda: [decoder.decode(r) for r in records], rounds=3, iterations=1)


def test_batch_decode(benchmark, decoder: BrdfDecoder) -> None:
    records = [LatentRecord(f"m{i}", np.full(8, i / _BATCH), np.ones(8)) for i in range(_BATCH)]
    benchmark.group = "decode-batch16"
    benchmark.extra_info["role"] = "candidate"
    tables = benchmark.pedantic(lambda: list(decoder.decode_many(records)), rounds=3, iterations=1)
    assert len(tables) == _BATCH


_QUERIES = 20_000


@pytest.fixture(scope="module")
def directions() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    wi, wo = rng.normal(size=(2, _QUERIES, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    return wi, wo


def test_query_baseline_merl_eval(benchmark, merl_file: Path, directions) -> None:
    """Looking up 20,000 direction pairs in the original MERL table."""
    brdf = read_merl(merl_file)
    benchmark.group = "decode-query"
    benchmark.extra_info["role"] = "baseline"
    benchmark(brdf.eval, *directions)


def test_query_decoded_material(benchmark, decoder: BrdfDecoder, record: LatentRecord, directions) -> None:
    """The same 20,000 lookups in a decoded material (decoded once, cached)."""
    from brdfcodec.codec import DecodedMaterial

    material = DecodedMaterial(record, decoder)
    material.eval(*directions)
    benchmark.group = "decode-query"
    benchmark.extra_info["role"] = "candidate"
    values = benchmark(material.eval, *directions)
    assert values.shape == (_QUERIES, 3) and np.isfinite(values).all()


# --- issue 14: layered decoding and refinement effort


#: Benchmark group → (encoder options, has a detail layer): the high-rate record with all three parts
#: (64 basis coefficients, the most a record with a detail layer carries, + a detail layer at 16 KB; the default
#: ``--project-base auto`` leaves a record with a detail layer unprojected), and the low-rate one (a 64 B record:
#: compact base + 53 basis coefficients), with its base never and always projected on the shared basis (format
#: 1.6; the default picks per material); all three with a latent (``latent="always"``: the baseline is the
#: record's base decode, which a record without a latent, format 2.1, does not have).
_LAYERED_CASES = {
    "decode-layered": ({"bytes": 16384}, True),
    "decode-layered-64B": ({"bytes": 64, "latent_dtype": "float16", "project_base": "never", "latent": "always"},
                           False),
    "decode-layered-64B-projected": ({"bytes": 64, "latent_dtype": "float16", "project_base": "always",
                                      "latent": "always"}, False),
}


@pytest.fixture(scope="module", params=sorted(_LAYERED_CASES))
def layered_case(request: pytest.FixtureRequest, merl_file: Path):
    from brdfcodec.format.layered_record import LayeredRecord

    options, has_detail = _LAYERED_CASES[request.param]
    record = BrdfEncoder(effort=0, **options).encode(read_merl(merl_file), name=request.param)
    assert isinstance(record, LayeredRecord) and record.basis is not None
    assert (record.detail is not None) == has_detail
    return request.param, record


#: Timed rounds of the layered benchmarks; each round decodes the base alone, then the layered record.
_PAIRED_ROUNDS = 60


def test_layered_decode(benchmark, decoder: BrdfDecoder, layered_case) -> None:
    """Base decode plus the record's layers (basis coefficients; the detail layer: zstandard, inverse DCT).

    Timed **paired**: every round first decodes the record's base alone (the baseline, timed in the round's
    setup), then the layered record (the candidate, timed by pytest-benchmark), so that a noisy machine's drift
    falls on both alike. The group's ratio is the median of the per-round ratios (``extra_info["paired_ratio"]``,
    read by ``conftest.py``); two benchmarks run one after the other instead varied from 1.26 to 1.87 over ten
    runs of an unchanged decoder.

    The shared basis is loaded (and its hash checked) once per decoder, like the weights: not timed here.
    """
    benchmark.group, record = layered_case
    benchmark.extra_info["role"] = "candidate"
    base = record.base()
    decoder.decode(record)  # loads the shared basis once
    base_seconds: list[float] = []

    def decode_base_timed() -> None:
        start = time.perf_counter()
        decoder.decode(base)
        base_seconds.append(time.perf_counter() - start)

    table = benchmark.pedantic(decoder.decode, args=(record,), setup=decode_base_timed,
                               rounds=_PAIRED_ROUNDS, warmup_rounds=2, iterations=1)
    assert table.shape == (3, 90, 90, 180)
    if benchmark.disabled:
        return
    layered_seconds = np.asarray(benchmark.stats.stats.data, dtype=float)
    paired_base = np.asarray(base_seconds[-len(layered_seconds):], dtype=float)  # setup also ran for the warm-up
    assert len(paired_base) == len(layered_seconds) == _PAIRED_ROUNDS
    benchmark.extra_info["paired_baseline_s"] = float(np.median(paired_base))
    benchmark.extra_info["paired_ratio"] = float(np.median(layered_seconds / paired_base))


def test_encode_effort_baseline_effort0(benchmark, merl_file: Path) -> None:
    encoder = BrdfEncoder(effort=0)
    benchmark.group = "encode-effort"
    benchmark.extra_info["role"] = "baseline"
    benchmark.pedantic(lambda: encoder.encode(read_merl(merl_file)), rounds=3, iterations=1)


def test_encode_default_effort(benchmark, merl_file: Path) -> None:
    """Read and encode at the default effort (what `bvae compress` does per file, after start-up)."""
    encoder = BrdfEncoder()
    encoder.decoder  # loaded once, as by the CLI before its first file  # noqa: B018
    benchmark.group = "encode-effort"
    benchmark.extra_info["role"] = "candidate"
    record = benchmark.pedantic(lambda: encoder.encode(read_merl(merl_file)), rounds=3, iterations=1)
    assert record.meta["effort"] == 1


# --- issue 48: the integer polish of a latent record's basis layer, at the budget the issue times (64 B)


def _timed_encode(benchmark, merl_file: Path, group: str, role: str,  # noqa: ANN001 - pytest-benchmark's fixture
                  **options: object) -> LatentRecord:
    """Read and encode ``merl_file`` with ``BrdfEncoder(latent_dtype="float16", **options)`` (its model loaded once,
    as by the CLI before its first file), timed as ``role`` of ``group``; the last record."""
    encoder = BrdfEncoder(latent_dtype="float16", **options)  # type: ignore[arg-type]
    encoder.decoder  # noqa: B018
    benchmark.group = group
    benchmark.extra_info["role"] = role
    return benchmark.pedantic(lambda: encoder.encode(read_merl(merl_file)), rounds=3, iterations=1)


def test_encode_64b_baseline_without_layer_polish(benchmark, merl_file: Path, monkeypatch) -> None:
    """Read and encode at 64 B with the layer polish off (``LAYER_POLISH_PASSES`` 0 at effort 1)."""
    from brdfcodec.codec import refine

    monkeypatch.setitem(refine.LAYER_POLISH_PASSES, 1, 0)
    _timed_encode(benchmark, merl_file, "encode-64B-layer-polish", "baseline", bytes=64)


def test_encode_64b_with_layer_polish(benchmark, merl_file: Path) -> None:
    """The same encode with the default polish of every packed or coded candidate layer."""
    record = _timed_encode(benchmark, merl_file, "encode-64B-layer-polish", "candidate", bytes=64)
    assert record.has_latent and record.meta["rate"]["record_bytes"] <= 64


# --- issue 48: records whose μ rides in the coded layer (format 2.5), offered beside the fixed-grid ones


def test_encode_64b_baseline_without_coded_mu(benchmark, merl_file: Path) -> None:
    """Read and encode at 64 B without the coded-μ candidates (``coded_mu_step=0``)."""
    record = _timed_encode(benchmark, merl_file, "encode-64B-coded-mu", "baseline", bytes=64, coded_mu_step=0)
    assert not record.coded_mu


def test_encode_64b_with_coded_mu(benchmark, merl_file: Path) -> None:
    """The same encode with the default candidates, coded μ among them."""
    record = _timed_encode(benchmark, merl_file, "encode-64B-coded-mu", "candidate", bytes=64)
    assert record.has_latent and record.meta["rate"]["record_bytes"] <= 64


def test_encode_max_relae_baseline_without_coded_mu(benchmark, merl_file: Path) -> None:
    """Read and encode to an error target (mapped RelAE 0.05) without the coded-μ records (``coded_mu_step=0``)."""
    record = _timed_encode(benchmark, merl_file, "encode-max-relae-coded-mu", "baseline", max_relae=0.05,
                           coded_mu_step=0)
    assert not record.coded_mu


def test_encode_max_relae_with_coded_mu(benchmark, merl_file: Path) -> None:
    """The same encode with the default candidates: the coded-μ records' size bisected below the ladder's choice."""
    record = _timed_encode(benchmark, merl_file, "encode-max-relae-coded-mu", "candidate", max_relae=0.05)
    assert record.has_latent


def test_encode_32b_baseline_with_one_coded_mu_grid(benchmark, merl_file: Path) -> None:
    """Read and encode at 32 B with the coded-μ candidates on 2^−3 alone (``coded_mu_step=3``)."""
    record = _timed_encode(benchmark, merl_file, "encode-32B-coded-mu-grids", "baseline", bytes=32, coded_mu_step=3)
    assert record.coded_mu in (0, 3)


def test_encode_32b_with_two_coded_mu_grids(benchmark, merl_file: Path) -> None:
    """The same encode with the default candidates: at 32 B, coded-μ records on 2^−3 and 2^−2, a pool each."""
    record = _timed_encode(benchmark, merl_file, "encode-32B-coded-mu-grids", "candidate", bytes=32)
    assert record.has_latent and record.meta["rate"]["record_bytes"] <= 32


def test_encode_36b_baseline_with_one_coded_mu_grid(benchmark, merl_file: Path) -> None:
    """Read and encode at 36 B with the coded-μ candidates on 2^−3 alone (``coded_mu_step=3``): the default above
    32 B before ``CODED_MU_COARSER_REACH``."""
    record = _timed_encode(benchmark, merl_file, "encode-36B-coded-mu-cap", "baseline", bytes=36, coded_mu_step=3)
    assert record.coded_mu in (0, 3)


def test_encode_36b_with_the_capped_coarser_grid(benchmark, merl_file: Path) -> None:
    """The same encode with the default candidates: at 36 B, 2^−2's records of at most 32 B beside 2^−3's."""
    record = _timed_encode(benchmark, merl_file, "encode-36B-coded-mu-cap", "candidate", bytes=36)
    assert record.has_latent and record.meta["rate"]["record_bytes"] <= 36
