"""The library's one thread setting (issue 39, 1): torch's threads inside encode and decode, restored after."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from threadpoolctl import threadpool_info

import brdfcodec as bc
from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.runtime import threads as blas_threads


@pytest.fixture(autouse=True)
def _library_setting_reset():
    yield
    bc.set_num_threads(None)


def test_the_setting_comes_from_the_call_then_the_environment_then_half_the_cores(monkeypatch) -> None:
    monkeypatch.delenv("BVAE_NUM_THREADS", raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert bc.get_num_threads() == blas_threads.default_thread_count()
    monkeypatch.setattr(blas_threads, "available_cores", lambda: 64)  # counts above the cores: test_thread_limits
    assert blas_threads.default_thread_count(2) == 1 and blas_threads.default_thread_count(64) == 8
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert bc.get_num_threads() == 3
    monkeypatch.setenv("BVAE_NUM_THREADS", "5")
    assert bc.get_num_threads() == 5
    monkeypatch.setenv("BVAE_NUM_THREADS", "many")  # not a count: ignored
    assert bc.get_num_threads() == 3
    bc.set_num_threads(2)
    assert bc.get_num_threads() == 2
    for bad in (0, -1, 1.5, "2", True):
        with pytest.raises(ValueError, match="positive integer"):
            bc.set_num_threads(bad)  # type: ignore[arg-type]


def _blas() -> set[int]:
    return {info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"}


def test_encode_and_decode_run_torch_on_the_librarys_threads_and_restore_the_callers(monkeypatch) -> None:
    from brdfcodec.codec import encoding

    seen: dict[str, tuple[int, set[int]]] = {}
    real = encoding.layer_records

    def spy(*args, **kwargs):
        seen["refinement"] = (torch.get_num_threads(), _blas())
        return real(*args, **kwargs)

    monkeypatch.setattr(encoding, "layer_records", spy)
    before = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        bc.set_num_threads(1)
        encoder = bc.BrdfEncoder(effort=1)
        record = encoder.encode(ANALYTIC_PRESETS["gold"].to_merl(), name="gold")
        assert seen["refinement"][0] == 1
        assert seen["refinement"][1] <= {1}  # numpy's BLAS on one thread meanwhile
        assert torch.get_num_threads() == 3  # the caller's setting is back

        decoder = encoder.decoder
        hook = decoder.network.register_forward_pre_hook(
            lambda module, args: seen.__setitem__("decode", (torch.get_num_threads(), _blas())))
        try:
            bc.set_num_threads(2)
            decoder.decode(LatentRecord("x", np.asarray(record.mu), np.ones(record.latent_dim)))
        finally:
            hook.remove()
        assert seen["decode"][0] == 2
        assert torch.get_num_threads() == 3
    finally:
        torch.set_num_threads(before)
