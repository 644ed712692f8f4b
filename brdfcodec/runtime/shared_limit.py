"""A process-wide setting changed while any caller needs it, restored when the last one is done.

numpy's BLAS thread count (OpenBLAS) is one setting for the whole process, so
decodes that overlap on several threads must share one change: the first to
enter applies it and keeps what restores it, the last to leave restores it,
also when its block raises.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator

__all__ = ["SharedLimit"]


class SharedLimit:
    """A setting that :meth:`held` blocks apply once between them.

    Parameters
    ----------
    apply : callable
        Changes the setting and returns the function that restores it.
    """

    def __init__(self, apply: Callable[[], Callable[[], None]]) -> None:
        self._apply = apply
        self._lock = threading.Lock()
        self._holders = 0
        self._restore: Callable[[], None] | None = None

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        """Run the enclosed block with the setting applied (safe to nest and to enter from several threads)."""
        with self._lock:
            if self._holders == 0:
                self._restore = self._apply()
            self._holders += 1
        try:
            yield
        finally:
            with self._lock:
                self._holders -= 1
                if self._holders == 0 and self._restore is not None:
                    restore, self._restore = self._restore, None
                    restore()
