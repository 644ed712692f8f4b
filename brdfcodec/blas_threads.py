"""Keep numpy's BLAS on one thread while the decoder alternates it with torch.

Decoding runs torch (the network, on its OpenMP threads) and numpy's BLAS
(basis sum, inverse DCT of the detail layer, slice interpolation) one after
the other. OpenBLAS' worker threads keep spinning for a while after each
call, so on a machine with few cores they take the cores torch's threads
need next: on 2 cores a layered decode took 27.3 ms with BLAS threaded and
21.6 ms with BLAS on one thread, a base-only decode 11.9 ms either way
(``python -m pytest benchmarks/test_bench_codec.py -k layered``; measured
before the layers moved ahead of the network, see ``BrdfDecoder``). The limit
is set for the duration of a decode only, through threadpoolctl, and the
caller's own BLAS setting is restored afterwards.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator
from typing import Any

__all__ = ["single_blas_thread"]


@functools.cache
def _controller() -> Any:
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


@contextlib.contextmanager
def single_blas_thread() -> Iterator[None]:
    """Run the enclosed block with numpy's BLAS limited to one thread (torch's threads are untouched)."""
    with _controller().limit(limits=1, user_api="blas"):
        yield
