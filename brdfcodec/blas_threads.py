"""Keep numpy's BLAS on one thread while the decoder mixes it with torch.

Decoding runs torch (the network, on its OpenMP threads) and numpy's BLAS
(basis sum, inverse DCT of the detail layer, slice interpolation) one after
the other. OpenBLAS' worker threads keep spinning for a while after each
call, so on a machine with few cores they take the cores torch's threads
need next: on 2 cores a layered decode took 27.3 ms with BLAS threaded and
21.6 ms with BLAS on one thread, a base-only decode 11.9 ms either way
(``python -m pytest benchmarks/test_bench_codec.py -k layered``, measured
with an earlier, slower basis sum). The limit
is set for the duration of a decode only, through threadpoolctl, and the
caller's own BLAS setting is restored afterwards; decodes that overlap on
several threads share one limit (:class:`~brdfcodec.shared_limit.SharedLimit`).
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from typing import Any

from brdfcodec.shared_limit import SharedLimit

__all__ = ["single_blas_thread"]


@functools.cache
def _controller() -> Any:
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def _release_openblas_control() -> None:
    """Let any thread set OpenBLAS' thread count next.

    threadpoolctl ≥ 3.6 lets only one "controlling" Python thread change a
    process-wide OpenBLAS pool (others are silently ignored), and a limit not
    used as a ``with`` block keeps that control. Our sets and restores are
    serialised by :class:`~brdfcodec.shared_limit.SharedLimit`'s lock, so control is released around each of them.
    """
    import threadpoolctl

    clear = getattr(getattr(threadpoolctl, "OpenBLASController", None), "clear_controlling_thread", None)
    if clear is not None:
        clear(force=True)


def _limit_blas_to_one_thread() -> Callable[[], None]:
    _release_openblas_control()
    limiter = _controller().limit(limits=1, user_api="blas")
    _release_openblas_control()

    def restore() -> None:
        _release_openblas_control()
        limiter.restore_original_limits()
        _release_openblas_control()

    return restore


_ONE_BLAS_THREAD = SharedLimit(_limit_blas_to_one_thread)


def single_blas_thread() -> contextlib.AbstractContextManager[None]:
    """Run the enclosed block with numpy's BLAS limited to one thread (torch's threads are untouched).

    Safe to nest and to enter from several threads at once: the BLAS setting
    found when the first block began is restored when the last one ends.
    The BLAS libraries are those loaded at the first call (numpy's).
    """
    return _ONE_BLAS_THREAD.held()
