"""Leave one core to numpy while torch runs the decoder network beside it.

A layered decode has two independent parts: the network's forward pass
(torch, compute-bound) and the record's layers (numpy: the basis sum, bound by
memory bandwidth, and the detail layer's inverse DCT). Run one after the other,
each gets every core in turn. Run side by side, the network gets all cores but
one and the layers get the last one.

On the 2-core development machine, the 16 KB analytic-gold record decoded in
15.3–15.7 ms side by side against 18.5–19.3 ms one after the other (base
alone: 12.4–12.9 ms). With torch keeping both cores while the layers ran on a
third thread, it took 21.5 ms: the threads fought for the cores. See
``python benchmarks/basis_sum_study.py``.

torch's intra-op thread count (OpenMP build) belongs to each thread: lowering
it on the decoding thread leaves the others alone, so each thread keeps and
restores its own count (nested blocks on one thread: the outermost one). The
call also sets the default a thread takes at its first parallel torch call, so
a thread that first uses torch while another thread is inside such a block
starts with one thread fewer; the block on the decoding thread lasts one
network pass (about 15 ms).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

import torch

__all__ = ["one_core_left"]

_NESTING = threading.local()


@contextlib.contextmanager
def one_core_left() -> Iterator[None]:
    """Run the enclosed block with torch on one intra-op thread fewer (at least one) on this thread.

    Safe to nest and to enter from several threads at once: each thread's count
    is restored, on that thread, when its outermost block ends, also when the
    block raises. With one thread already, nothing is changed.
    """
    depth = getattr(_NESTING, "depth", 0)
    saved = torch.get_num_threads() if depth == 0 else 1
    if saved > 1:
        torch.set_num_threads(saved - 1)
    _NESTING.depth = depth + 1
    try:
        yield
    finally:
        _NESTING.depth = depth
        if saved > 1:
            torch.set_num_threads(saved)
