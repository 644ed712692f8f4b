"""The host decode's passes after the network, compiled (Numba): the stepping of
:func:`~brdfcodec.representation.network_io.stepped_table` and the exponentials' arguments before it.

The host decode's cost after the network is the geometric stepping through each gap between kept φd slices,
the rounding to float32 and the below-horizon fill: about 4 million float64 steps a table. As NumPy ufunc calls
over blocks of θh rows it is bound by call overhead and an interleaving copy; compiled, one pass writes each bin
once, in φd order. The arithmetic is the NumPy path's, operation for operation and in the same order — ``current −
factor`` rounded to float32 once, then ``current ·= q`` — compiled without fast-math, so no operation is fused or
reordered and the output is bit for bit the NumPy path's (``tests/test_stepped_kernel.py`` checks it).

Numba is a dependency of the package; where it cannot be imported (a platform without its wheels),
:func:`compiled_stepping` returns None and the NumPy path runs. The kernel is compiled on first use and cached on
disk (Numba's cache: next to this file, or the user's cache directory where that is read-only): the first decode in
a fresh environment takes longer. It runs without Numba's threading layer (no second OpenMP pool
beside torch's, nothing unsafe across ``fork``): the caller splits the θh rows over its own threads, the kernel
releasing the GIL.
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Callable

import numpy as np

from brdfcodec.conventions import KEPT_PHI_D_SLICES, N_KEPT_SLICES

__all__ = ["compiled_log_arguments", "compiled_stepping", "invalid_runs", "whole_gaps"]

#: Bins from one kept slice to the next (a compile-time constant of the kernel: its inner loop unrolled), and the
#: gaps between the 21 kept slices (``conventions.KEPT_PHI_D_SLICES``: 20 gaps of 9 fill the 180 bins).
_GAP = KEPT_PHI_D_SLICES[1] - KEPT_PHI_D_SLICES[0]
_GAP_COUNT = N_KEPT_SLICES - 1

#: Set to 1 to skip the compiled passes (the NumPy and torch paths then run): for comparisons and debugging.
DISABLE_VARIABLE = "BRDFCODEC_NO_JIT"


def _compiled(function: Callable[..., None], *example: object) -> Callable[..., None] | None:
    """``function`` compiled by Numba and run once on ``example`` (small arrays of the real calls' types), or None
    where Numba is switched off, cannot be imported, or fails to compile (a warning then says so): the caller
    takes the NumPy path. Cached on disk where Numba finds a writable cache folder, else compiled per process."""
    if os.environ.get(DISABLE_VARIABLE, "") not in ("", "0"):
        return None
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is a dependency; platforms without its wheels
        return None
    try:
        try:
            kernel = numba.njit(cache=True, nogil=True, fastmath=False)(function)
        except RuntimeError:  # no writable cache folder ("no locator available"): compiled in this process only
            kernel = numba.njit(cache=False, nogil=True, fastmath=False)(function)
        kernel(*example)
    except Exception as error:  # noqa: BLE001 - any compiler failure: the NumPy path, bit for bit the same output
        warnings.warn(f"brdfcodec: the compiled decode passes are unavailable ({type(error).__name__}: {error}); "
                      f"the NumPy path runs (same tables, slower)", RuntimeWarning, stacklevel=3)
        return None
    return kernel


@functools.cache
def compiled_stepping() -> Callable[..., None] | None:
    """The compiled stepping kernel, or None where Numba cannot be imported or ``BRDFCODEC_NO_JIT=1``.

    The kernel's signature: ``kernel(start, ratio, factors, runs, whole, fill, masked, out, first_row, stop_row)``
    with

    - ``start`` float64 (N, 90, 90, 21) and ``ratio`` float64 (N, 90, 90, 20), C-contiguous, N the leading indices
      times the 3 channels (channel last of them);
    - ``factors`` float64 (3,): ``factor_c`` per channel;
    - ``runs`` int64 (90, 90, R, 2): per (θh, θd) cell, up to R runs ``[low, high)`` of φd bins set to ``fill``
      (float32) when ``masked`` (unused runs: ``low == high``; :func:`invalid_runs`);
    - ``whole`` bool (90, 90, 20): gaps whose 9 bins are all set to ``fill`` when ``masked``, without being
      stepped (:func:`whole_gaps`: about a fifth of a table's gaps lie wholly below the horizon; the runs then
      need not cover them);
    - ``out`` float32 (N, 90, 90, 180), C-contiguous, written at θh rows ``first_row`` … ``stop_row − 1``
      (threads may write disjoint row ranges at once: the kernel releases the GIL).
    """
    kept = _GAP_COUNT + 1
    return _compiled(_stepping, np.ones((3, 1, 1, kept)), np.ones((3, 1, 1, kept - 1)), np.ones(3),
                     np.zeros((1, 1, 1, 2), dtype=np.int64), np.zeros((1, 1, kept - 1), dtype=np.bool_),
                     np.float32(-1.0), True,
                     np.empty((3, 1, 1, _GAP_COUNT * _GAP), dtype=np.float32), 0, 1)


@functools.cache
def compiled_log_arguments() -> Callable[..., None] | None:
    """The compiled pass before the exponentials, or None (as :func:`compiled_stepping`).

    ``kernel(mapped, log_range, steps, x, gaps, first_row, stop_row)``: from clamped mapped slices ``mapped``
    float32 (3, 21, 90, 90) (network layout, C-contiguous), ``x = L · float64(m)`` into ``x`` float64
    (3, 90, 90, 21) and ``(x_b − x_a) / n`` into ``gaps`` float64 (3, 90, 90, 20), kept slice last, at θh rows
    ``first_row`` … ``stop_row − 1`` (threads may take disjoint row ranges at once) — the operations of
    ``codec/device_decode.py:table_from_mapped_host``'s torch path, in its order.
    """
    kept = _GAP_COUNT + 1
    return _compiled(_log_arguments, np.ones((3, kept, 1, 1), dtype=np.float32), 1.0, np.full(kept - 1, 9.0),
                     np.empty((3, 1, 1, kept)), np.empty((3, 1, 1, kept - 1)), 0, 1)


def invalid_runs(invalid: np.ndarray) -> np.ndarray:
    """The runs of True along φd of each (θh, θd) cell of ``invalid`` (90, 90, 180), as :func:`compiled_stepping`
    reads them: int64 (90, 90, R, 2) of ``[low, high)``, R the most runs of any cell (at least 1), unused runs
    ``[0, 0)``."""
    flags = np.asarray(invalid, dtype=np.int8)
    edges = np.diff(flags, axis=-1, prepend=0, append=0)
    most = max(1, int((edges == 1).sum(axis=-1).max(initial=0)))
    runs = np.zeros((*flags.shape[:-1], most, 2), dtype=np.int64)
    for cell in zip(*np.nonzero(flags.any(axis=-1)), strict=True):
        starts, = np.nonzero(edges[cell] == 1)
        stops, = np.nonzero(edges[cell] == -1)
        runs[cell][: len(starts), 0], runs[cell][: len(stops), 1] = starts, stops
    return runs


def whole_gaps(invalid: np.ndarray) -> np.ndarray:
    """Per (θh, θd) cell and gap between kept slices, whether all of the gap's bins (``g·9 … g·9 + 8``) are True
    in ``invalid`` (90, 90, 180): bool (90, 90, 20), as :func:`compiled_stepping` reads it."""
    flags = np.asarray(invalid, dtype=bool)
    return flags[..., : _GAP_COUNT * _GAP].reshape(*flags.shape[:-1], _GAP_COUNT, _GAP).all(axis=-1)


def _stepping(start: np.ndarray, ratio: np.ndarray, factors: np.ndarray, runs: np.ndarray, whole: np.ndarray,
              fill: np.float32, masked: bool, out: np.ndarray, first_row: int,
              stop_row: int) -> None:  # pragma: no cover - compiled
    count, _, columns, kept = start.shape
    gaps = kept - 1
    last = gaps * _GAP - 1  # bin 179: the last gap's ninth step lands on it, then the last kept slice's value
    for n in range(count):
        factor = factors[n % 3]
        for h in range(first_row, stop_row):
            for d in range(columns):
                for g in range(gaps):
                    first = g * _GAP
                    if masked and whole[h, d, g]:  # every bin of the gap is filled: nothing to step
                        for j in range(_GAP):
                            out[n, h, d, first + j] = fill
                        continue
                    current = start[n, h, d, g]
                    q = ratio[n, h, d, g]
                    for j in range(_GAP):
                        out[n, h, d, first + j] = np.float32(current - factor)
                        current *= q  # one step more than used at j = 8: the value is not read
                out[n, h, d, last] = np.float32(start[n, h, d, gaps] - factor)
                if masked:
                    for r in range(runs.shape[2]):
                        for b in range(runs[h, d, r, 0], runs[h, d, r, 1]):
                            out[n, h, d, b] = fill


def _log_arguments(mapped: np.ndarray, log_range: float, steps: np.ndarray, x: np.ndarray, gaps: np.ndarray,
                   first_row: int, stop_row: int) -> None:  # pragma: no cover - compiled
    channels, kept, _, columns = mapped.shape
    for c in range(channels):
        for h in range(first_row, stop_row):  # one (θh, θd) cell at a time: its 21 slices read once, written in order
            for d in range(columns):
                previous = np.float64(mapped[c, 0, h, d]) * log_range
                x[c, h, d, 0] = previous
                for k in range(1, kept):
                    value = np.float64(mapped[c, k, h, d]) * log_range
                    x[c, h, d, k] = value
                    gaps[c, h, d, k - 1] = (value - previous) / steps[k - 1]
                    previous = value
