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

torch's intra-op thread count is one setting for the whole process, so
overlapping blocks share one limit (:class:`~brdfcodec.shared_limit.SharedLimit`):
the first to enter saves the count, and the last to leave restores it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable

import torch

from brdfcodec.shared_limit import SharedLimit

__all__ = ["one_core_left"]


def _one_thread_fewer() -> Callable[[], None]:
    saved = torch.get_num_threads()
    torch.set_num_threads(max(1, saved - 1))
    return lambda: torch.set_num_threads(saved)


_ONE_CORE_LEFT = SharedLimit(_one_thread_fewer)


def one_core_left() -> contextlib.AbstractContextManager[None]:
    """Run the enclosed block with torch on one intra-op thread fewer (at least one).

    Safe to nest and to enter from several threads at once: the count found
    when the first block began is restored when the last one ends, also when
    the block raises.
    """
    return _ONE_CORE_LEFT.held()
