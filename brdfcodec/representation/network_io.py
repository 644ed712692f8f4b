"""Tables to network inputs and network outputs back to tables: the two ends of the β-VAE.

Encoding side: a stored table (3, 90, 90, 180) becomes the network input
(63, 90, 90), its 21 kept φd slices log-mapped with invalid entries 0, and
the mask of valid entries (:func:`network_input_from_table`).

Decoding side (``spec/conventions.md`` §7): the decoder's mapped slices are
clamped to the mapped domain (:func:`~brdfcodec.representation.mapping.clamp_mapped`,
once), interpolated in the mapped domain to the φd bins asked for, and
unmapped to stored units (:func:`table_from_mapped`).

>>> import numpy as np
>>> from brdfcodec.conventions import NETWORK_INPUT_SHAPE
>>> ones = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)   # reflectance 1/sr everywhere
>>> table = table_from_network_output(ones, phi_d_bins=[0, 4])
>>> table.shape, table.dtype
((3, 90, 90, 2), dtype('float32'))
>>> np.round(table[:, 0, 0, 0] * [1.0, 1.15, 1.66] / 1500, 5)   # back to 1/sr
array([1., 1., 1.])
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import (
    EPSILON,
    KEPT_PHI_D_SLICES,
    MERL_COLOR_SCALE,
    N_CHANNELS,
    N_KEPT_SLICES,
    N_PHI_D,
    N_THETA_D,
    N_THETA_H,
    NETWORK_INPUT_SHAPE,
)
from brdfcodec.representation.layout import (
    from_network_layout,
    select_kept_slices,
    to_network_layout,
    validate_phi_d_bins,
)
from brdfcodec.representation.mapping import LOG_RANGE, clamp_mapped, map_values
from brdfcodec.representation.mask import validity_mask
from brdfcodec.representation.stepped_kernel import compiled_stepping, invalid_runs, whole_gaps
from brdfcodec.runtime.threads import get_num_threads

__all__ = [
    "network_input_from_table", "over_theta_h_rows", "reflectance_from_mapped", "stepped_table",
    "table_from_mapped", "table_from_network_output",
]


def network_input_from_table(
    values: npt.ArrayLike, mask: npt.ArrayLike | None = None
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
    """Network input and its mask for one table.

    Parameters
    ----------
    values : array_like, shape (3, 90, 90, 180)
        Stored MERL values.
    mask : array_like of bool, shape (3, 90, 90, 180), optional
        Valid entries; :func:`~brdfcodec.representation.mask.validity_mask` of ``values`` by default.

    Returns
    -------
    inputs : ndarray of float32, shape (63, 90, 90)
        Log-mapped kept slices in the network layout; invalid entries are 0.
    mask : ndarray of bool, shape (63, 90, 90)
        Valid entries, same layout.
    """
    table = np.asarray(values)
    valid = validity_mask(table) if mask is None else np.asarray(mask, dtype=bool)
    kept_mask = select_kept_slices(valid)
    kept_values = np.where(kept_mask, select_kept_slices(table), 0.0)
    mapped = np.where(kept_mask, map_values(kept_values), 0.0).astype(np.float32)
    return to_network_layout(mapped), to_network_layout(kept_mask)


@functools.cache
def _interpolation_steps(phi_d_bins: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, tuple[tuple[np.ndarray, np.ndarray], ...]]:
    """How the chosen bins are reached from the kept slices (built once per choice of bins).

    Every φd bin p lies in the gap that starts at a kept slot g (the last kept bin, 179, in a gap of its own)
    at offset j = p − kept[g]; the gap holds n = kept[g + 1] − kept[g] bins.

    Returns
    -------
    gaps : ndarray of intp
        The gaps the bins need (their left kept slots), sorted.
    steps : ndarray of float64
        Each needed gap's length n (1 for the last kept bin's gap, where no step is taken).
    writes : tuple of (positions, columns)
        For each offset j = 0, 1, …: the positions in ``gaps`` and the output columns of the bins at offset j.
    """
    kept = np.asarray(KEPT_PHI_D_SLICES)
    bins = np.asarray(phi_d_bins, dtype=np.intp)
    gap_of = np.searchsorted(kept, bins, side="right") - 1
    offset = bins - kept[gap_of]
    gaps = np.unique(gap_of)
    lengths = np.diff(kept).astype(np.float64)
    steps = np.where(gaps < N_KEPT_SLICES - 1, lengths[np.minimum(gaps, N_KEPT_SLICES - 2)], 1.0)
    position = np.searchsorted(gaps, gap_of)
    writes = tuple(
        (position[offset == j], np.flatnonzero(offset == j)) for j in range(int(offset.max()) + 1 if len(bins) else 0)
    )
    for array in (gaps, steps, *(a for pair in writes for a in pair)):
        array.setflags(write=False)
    return gaps, steps, writes


def _scaled_expm1(mapped: npt.ArrayLike, phi_d_bins: Sequence[int] | None, factor: np.ndarray) -> np.ndarray:
    """``factor_c · expm1(L · m)`` at the chosen φd bins, m the mapped value interpolated there, as float32.

    The numerically sensitive part of a decode (``spec/bvae-format.md`` §9), in float64: the interpolated
    mapped value times the log range ``L`` is ``x = x_a + j·(x_b − x_a)/n`` between kept slices a and b, so
    ``exp(x)`` is ``exp(x_a)·q^j`` with ``q = exp((x_b − x_a)/n)`` — one exponential per kept slice and one
    per gap, then a product per bin (a geometric sequence, float64 rounding at each step: relative error below
    1e-14 after the 9 steps of a gap). ``exp(x) − 1`` in float64 keeps dark entries (x near 0) to about
    1e-16 absolute; the single rounding to float32 is last. The same operations in the same order for any
    choice of bins, so a bin decoded alone equals the same bin of the full table.

    Parameters
    ----------
    mapped : array_like, shape (..., 63, 90, 90)
        Clamped mapped slices (network layout).
    phi_d_bins : sequence of int or None
        The bins, each in [0, 180); all by default.
    factor : ndarray of float64, shape (3,)
        Per-channel factor on ``expm1`` (ε / S_c for stored units, ε for reflectance, times the energy bound).

    Returns
    -------
    ndarray of float32, shape (..., 3, 90, 90, K)
    """
    bins = validate_phi_d_bins(phi_d_bins)
    array = np.asarray(mapped, dtype=np.float32)
    if array.shape[-3:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"mapped must have shape (..., {', '.join(map(str, NETWORK_INPUT_SHAPE))}), got {array.shape}")
    kept = from_network_layout(array)  # (..., 3, 90, 90, 21), a view
    scale = np.asarray(factor, dtype=np.float64).reshape(N_CHANNELS, 1, 1, 1)
    if bins == _ALL_BINS:
        return _scaled_expm1_all(kept, scale)
    gaps, steps, writes = _interpolation_steps(bins)
    low = kept[..., gaps].astype(np.float64)
    low *= LOG_RANGE
    high = kept[..., np.minimum(gaps + 1, N_KEPT_SLICES - 1)].astype(np.float64)
    high *= LOG_RANGE
    ratio = np.subtract(high, low, out=high)
    ratio /= steps
    ratio = np.exp(ratio, out=ratio)  # q per gap
    current = np.exp(low, out=low)  # scale · exp(x) at the gap's left kept slice, then one step further each round
    current *= scale
    out = np.empty((*kept.shape[:-1], len(bins)), dtype=np.float32)
    for j, (positions, columns) in enumerate(writes):
        if len(columns):
            out[..., columns] = current[..., positions] - scale
        if j + 1 < len(writes):
            current *= ratio
    return out


_ALL_BINS = tuple(range(N_PHI_D))
_GAP = KEPT_PHI_D_SLICES[1] - KEPT_PHI_D_SLICES[0]  # 9 bins from one kept slice to the next, but the last gap
# The last gap, 171 → 179, holds 8 bins and its end: 20 gaps of 9 fill the 180 bins (stepped_table relies on it).
assert (N_KEPT_SLICES - 1) * _GAP == N_PHI_D and KEPT_PHI_D_SLICES[-1] == N_PHI_D - 1


#: θh rows stepped at once by :func:`_scaled_expm1_all`: its working arrays (about 0.5 MB) stay in cache.
_ROWS_PER_BLOCK = 10


def _scaled_expm1_all(kept: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """:func:`_scaled_expm1` of all 180 bins: the exponentials of :func:`_kept_exponentials`, then
    :func:`stepped_table`."""
    start, ratio = _kept_exponentials(kept, scale)
    return stepped_table(start, ratio, scale.reshape(-1))


def _kept_exponentials(kept: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``scale · exp(x)`` at the kept slices and ``q = exp((x_b − x_a) / n)`` per gap, ``x = L · m`` (float64).

    Parameters
    ----------
    kept : ndarray of float32, shape (..., 3, 90, 90, 21)
    scale : ndarray of float64, shape (3, 1, 1, 1)

    Returns
    -------
    start : ndarray of float64, shape (..., 3, 90, 90, 21)
    ratio : ndarray of float64, shape (..., 3, 90, 90, 20)
    """
    x = kept.astype(np.float64)
    x *= LOG_RANGE
    ratio = x[..., 1:] - x[..., :-1]
    ratio /= _GAP_LENGTHS
    ratio = np.exp(ratio, out=ratio)
    start = np.exp(x, out=x)
    start *= scale
    return start, ratio


def stepped_table(
    start: np.ndarray,
    ratio: np.ndarray,
    factor: np.ndarray,
    *,
    invalid: np.ndarray | None = None,
    fill: float = 0.0,
    out: np.ndarray | None = None,
    compiled: bool = False,
    threads: int | None = None,
) -> npt.NDArray[np.float32]:
    """All 180 bins from the kept slices' exponentials: ``current − factor_c`` rounded to float32 once, ``current``
    stepped by ``q`` through each gap (:func:`_scaled_expm1`'s geometric sequence), float64 throughout.

    The exponentials may come from NumPy (:func:`_kept_exponentials`) or from another library (the codec's host
    decode may take them from torch, whose float64 ``exp`` is vectorised on every CPU): the steps, and so the
    rounding, are the same.
    Block by block of θh rows, each round writes one offset of every gap into a small contiguous float32 slab, and
    one transposed copy puts the slab in φd order, then the mask is applied while the block is in cache: a strided
    write per round, or whole-table passes, were several times slower (memory traffic, not arithmetic, is the cost).

    Parameters
    ----------
    start : ndarray of float64, shape (..., 3, 90, 90, 21)
        ``factor_c · exp(L · m)`` at the kept slices.
    ratio : ndarray of float64, shape (..., 3, 90, 90, 20)
        ``exp((x_b − x_a) / n)`` per gap between kept slices.
    factor : ndarray of float64, shape (3,)
        The per-channel factor on ``expm1`` that ``start`` holds.
    invalid : ndarray of bool, shape (90, 90, 180), optional
        Bins set to ``fill`` (the below-horizon bins, :func:`~brdfcodec.representation.mask.horizon_mask`'s
        complement); none by default.
    fill : float, default 0.0
        The value of the ``invalid`` bins.
    out : ndarray of float32, shape (..., 3, 90, 90, 180), optional
        Where to write the table (C-contiguous); a new array by default.
    compiled : bool, default False
        Step in one compiled pass (:mod:`~brdfcodec.representation.stepped_kernel`), bit for bit the same table and
        faster, where Numba imports (else the NumPy path). Its first use in a process imports Numba and loads the
        kernel, a one-time cost in time and memory: for batch decodes, not for one table
        (``benchmarks/test_bench_decode_path.py``, ``benchmarks/test_bench_memory.py``).
    threads : int, optional
        Threads of the compiled pass (the NumPy path runs on the calling thread): the codec's thread count by
        default (:func:`~brdfcodec.runtime.threads.get_num_threads`).

    Returns
    -------
    ndarray of float32, shape (..., 3, 90, 90, 180)
        ``out`` when given.
    """
    lead = start.shape[:-1]  # (..., 3, 90, 90)
    if out is None:
        out = np.empty((*lead, N_PHI_D), dtype=np.float32)
    elif out.shape != (*lead, N_PHI_D) or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float32 array of shape {(*lead, N_PHI_D)}, got {out.dtype} "
                         f"{out.shape}")
    last = N_KEPT_SLICES - 1
    filler = np.float32(fill)
    scales = np.asarray(factor, dtype=np.float64).reshape(N_CHANNELS)
    kernel = compiled_stepping() if compiled else None
    if (kernel is not None and len(lead) >= 3 and lead[-3:] == (N_CHANNELS, N_THETA_H, N_THETA_D)
            and start.shape[-1] == N_KEPT_SLICES and ratio.shape == (*lead, last)
            and (invalid is None or invalid.shape == (N_THETA_H, N_THETA_D, N_PHI_D))):
        # one compiled pass, bit for bit the steps below (representation/stepped_kernel.py), its θh rows split over
        # the codec's threads; the shapes checked here, as the compiled code does not check its indices
        count = int(np.prod(lead[:-2]))
        arguments = (np.ascontiguousarray(start, dtype=np.float64).reshape(count, N_THETA_H, N_THETA_D, -1),
                     np.ascontiguousarray(ratio, dtype=np.float64).reshape(count, N_THETA_H, N_THETA_D, -1), scales,
                     *_runs_of(invalid), filler, invalid is not None,
                     out.reshape(count, N_THETA_H, N_THETA_D, N_PHI_D))
        over_theta_h_rows(kernel, *arguments, threads=threads)
        return out
    spans = None if invalid is None else _invalid_spans(invalid)
    for index in np.ndindex(*lead[:-2]):  # every leading index and channel
        channel_scale = scales[index[-1]]
        for block, row in enumerate(range(0, lead[-2], _ROWS_PER_BLOCK)):
            rows = (*index, slice(row, row + _ROWS_PER_BLOCK))
            current = start[(*rows, Ellipsis, slice(0, last))].copy()  # (rows, 90, 20)
            step = ratio[rows]
            slab = np.empty((_GAP, *current.shape), dtype=np.float32)
            for j in range(_GAP):
                np.subtract(current, channel_scale, out=slab[j], casting="same_kind")
                if j + 1 < _GAP:
                    current *= step
            target = out[rows]  # (rows, 90, 180), a view
            # every gap as if it held 9 bins: the last one's ninth lands on bin 179, written next
            target.reshape(*target.shape[:2], last, _GAP)[...] = slab.transpose(1, 2, 3, 0)
            # bin 179, a kept slice of its own
            np.subtract(start[(*rows, Ellipsis, last)], channel_scale, out=target[..., -1], casting="same_kind")
            if spans is not None and spans[block] is not None:
                low, high = spans[block]  # the θd columns of the block's rows that hold any invalid bin
                np.copyto(target[:, low:high], filler, where=invalid[row : row + _ROWS_PER_BLOCK, low:high])
    return out


#: Per read-only ``invalid`` array (by identity, the array kept alive): for each block of θh rows, the θd columns
#: that hold an invalid bin (the horizon's are a suffix, all but a third of the table is whole).
_SPANS: dict[int, tuple[np.ndarray, list[tuple[int, int] | None]]] = {}


def over_theta_h_rows(kernel: Callable[..., None], *arguments: object, threads: int | None = None) -> None:
    """Run a compiled pass over the 90 θh rows, split into disjoint row ranges over threads.

    Parameters
    ----------
    kernel : callable
        Called as ``kernel(*arguments, first_row, stop_row)`` once per range; it must release the GIL and write
        only the rows ``first_row`` … ``stop_row − 1`` of its outputs.
    *arguments : object
        The kernel's arguments before the row range.
    threads : int, optional
        Ranges run at once (at most 90): the codec's thread count by default
        (:func:`~brdfcodec.runtime.threads.get_num_threads`); 1 runs the kernel once, on the calling thread.
    """
    parts = max(1, min(get_num_threads() if threads is None else int(threads), N_THETA_H))
    if parts == 1:
        kernel(*arguments, 0, N_THETA_H)
        return
    bounds = [N_THETA_H * i // parts for i in range(parts + 1)]
    pool = _row_pool(parts)
    for done in [pool.submit(kernel, *arguments, low, high) for low, high in zip(bounds[:-1], bounds[1:], strict=True)]:
        done.result()


@functools.cache
def _row_pool(threads: int) -> ThreadPoolExecutor:
    """The threads that run the compiled pass over disjoint θh rows (one pool per thread count, kept; a forked
    child starts without them: its inherited pools have no threads, and would never run a job)."""
    return ThreadPoolExecutor(max_workers=threads, thread_name_prefix="brdfcodec-step")


if hasattr(os, "register_at_fork"):  # not on Windows, which does not fork
    os.register_at_fork(after_in_child=_row_pool.cache_clear)


#: Per read-only ``invalid`` array (by identity, the array kept alive): its runs as the compiled pass reads them.
_RUNS: dict[int, tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]] = {}
#: The runs and whole gaps of the compiled pass when no bin is filled.
_NO_RUNS = (np.zeros((N_THETA_H, N_THETA_D, 1, 2), dtype=np.int64),
            np.zeros((N_THETA_H, N_THETA_D, N_KEPT_SLICES - 1), dtype=np.bool_))


def _runs_of(invalid: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~brdfcodec.representation.stepped_kernel.invalid_runs` and
    :func:`~brdfcodec.representation.stepped_kernel.whole_gaps` of ``invalid`` (cached for a read-only array)."""
    if invalid is None:
        return _NO_RUNS
    cached = _RUNS.get(id(invalid))
    if cached is not None and cached[0] is invalid:
        return cached[1]
    whole = whole_gaps(invalid)
    # the kernel fills the whole gaps itself: the runs cover only the bins of the other gaps, and the last bin
    # (the last gap's ninth, which the kernel writes again from the last kept slice)
    in_whole = np.repeat(whole, _GAP, axis=-1)
    in_whole[..., -1] = False
    runs = invalid_runs(invalid & ~in_whole), whole
    if not invalid.flags.writeable:
        if len(_RUNS) > 8:
            _RUNS.clear()
        _RUNS[id(invalid)] = (invalid, runs)
    return runs


def _invalid_spans(invalid: np.ndarray) -> list[tuple[int, int] | None]:
    """For each block of :data:`_ROWS_PER_BLOCK` θh rows, ``(low, high)``: the θd columns from the first to the last
    that hold an invalid bin, or None where none does (cached for a read-only array)."""
    cached = _SPANS.get(id(invalid))
    if cached is not None and cached[0] is invalid and len(cached[1]) == -(-invalid.shape[0] // _ROWS_PER_BLOCK):
        return cached[1]
    columns = invalid.any(axis=-1)  # (θh, θd)
    spans: list[tuple[int, int] | None] = []
    for row in range(0, invalid.shape[0], _ROWS_PER_BLOCK):
        hit = np.flatnonzero(columns[row : row + _ROWS_PER_BLOCK].any(axis=0))
        spans.append((int(hit[0]), int(hit[-1]) + 1) if len(hit) else None)
    if not invalid.flags.writeable:
        if len(_SPANS) > 8:
            _SPANS.clear()
        _SPANS[id(invalid)] = (invalid, spans)
    return spans


_GAP_LENGTHS = np.diff(np.asarray(KEPT_PHI_D_SLICES)).astype(np.float64)
_GAP_LENGTHS.setflags(write=False)


_STORED_PER_EXPM1 = EPSILON / np.asarray(MERL_COLOR_SCALE, dtype=np.float64)
_REFLECTANCE_PER_EXPM1 = np.full(N_CHANNELS, EPSILON, dtype=np.float64)


def _check_scale(scale: float) -> float:
    value = float(scale)
    if not (np.isfinite(value) and value >= 0.0):
        raise ValueError(f"scale must be a finite factor ≥ 0 on reflectance, got {scale!r}")
    return value


def reflectance_from_mapped(
    mapped: npt.ArrayLike, *, phi_d_bins: Sequence[int] | None = None, scale: float = 1.0
) -> npt.NDArray[np.float32]:
    """Reflectance (1/sr) from mapped slices in the mapped domain: :func:`table_from_mapped` without the colour scale.

    The mapping is the same function of reflectance in every channel, so
    reflectance is ``ε · expm1(·)`` directly; going through stored units would
    divide by the colour scale and multiply it back.

    Parameters
    ----------
    mapped, phi_d_bins
        As for :func:`table_from_mapped`.
    scale : float, default 1.0
        Factor on reflectance (the energy bound, ``spec/bvae-format.md`` §6 step 5), applied to the
        interpolated table.

    Returns
    -------
    ndarray of float32, shape (..., 3, 90, 90, K)
        Finite and ≥ 0; equal to ``reflectance_from_stored(table_from_mapped(mapped))``
        up to float32 rounding.
    """
    return _scaled_expm1(mapped, phi_d_bins, _REFLECTANCE_PER_EXPM1 * _check_scale(scale))


def table_from_mapped(
    mapped: npt.ArrayLike, *, phi_d_bins: Sequence[int] | None = None, scale: float = 1.0
) -> npt.NDArray[np.float32]:
    """Table (or chosen φd bins) in stored units from mapped slices already in the mapped domain.

    Parameters
    ----------
    mapped : array_like, shape (..., 63, 90, 90)
        Mapped values in ``[0, MAPPED_MAX]`` in the network layout (clamped
        decoder output: :meth:`brdfcodec.codec.BrdfDecoder.decode_mapped`).
        Values outside the domain are not checked; use
        :func:`table_from_network_output` for raw network output.
    phi_d_bins : sequence of int, optional
        φd bins to produce, each in [0, 180); all 180 by default. One bin
        costs 1/180 of the full table.
    scale : float, default 1.0
        Factor ≥ 0 on reflectance, applied after the interpolation (the energy
        bound of an edited record, ``spec/bvae-format.md`` §6 step 5).

    Returns
    -------
    ndarray of float32, shape (..., 3, 90, 90, K)
        Stored MERL values, finite and ≥ 0: the slices are interpolated in the
        mapped domain (``spec/conventions.md`` §7), then unmapped (§4), in
        float64 and rounded to float32 once (``spec/bvae-format.md`` §9; see
        :func:`_scaled_expm1`): a kept bin equals
        :func:`~brdfcodec.representation.mapping.unmap_values` of the
        decoder's slice in float64, rounded to float32.
    """
    return _scaled_expm1(mapped, phi_d_bins, _STORED_PER_EXPM1 * _check_scale(scale))


def table_from_network_output(
    output: npt.ArrayLike, *, phi_d_bins: Sequence[int] | None = None
) -> npt.NDArray[np.float32]:
    """Table in stored units from raw network output (any values): clamp once, then :func:`table_from_mapped`.

    Parameters
    ----------
    output : array_like, shape (..., 63, 90, 90)
        Mapped values in the network layout; clamped to ``[0, MAPPED_MAX]``
        first (NaN becomes 0).
    phi_d_bins : sequence of int, optional
        As for :func:`table_from_mapped`.

    Returns
    -------
    ndarray of float32, shape (..., 3, 90, 90, K)
    """
    return table_from_mapped(clamp_mapped(np.asarray(output, dtype=np.float32)), phi_d_bins=phi_d_bins)
