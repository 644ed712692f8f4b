"""The β-VAE's view of a table: log mapping, kept φd slices, interpolation back to 180.

Tables are in MERL layout ``[channel, θh, θd, φd]`` and MERL *stored* units
(the numbers in the file; multiply by
:data:`~brdfcodec.conventions.MERL_COLOR_SCALE` for reflectance in 1/sr).
The mapping of ``spec/conventions.md`` §4 is, per channel c,

.. math::

    \\hat\\rho = \\frac{\\log(\\rho S_c + \\varepsilon) - \\log\\varepsilon}
                     {\\log(1 + \\varepsilon) - \\log\\varepsilon}
             = \\frac{\\operatorname{log1p}(\\rho S_c / \\varepsilon)}{\\operatorname{log1p}(1/\\varepsilon)}

with ε = 0.01, so 0 maps to 0 and a reflectance of 1/sr maps to 1.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import (
    EPSILON,
    KEPT_PHI_D_SLICES,
    MAPPED_MAX,
    MERL_COLOR_SCALE,
    N_CHANNELS,
    N_KEPT_SLICES,
    N_PHI_D,
    NETWORK_INPUT_SHAPE,
    TABLE_SHAPE,
)

__all__ = [
    "from_network_input",
    "kept_slots_for_bins",
    "table_from_network_output",
    "interpolate_slices",
    "map_values",
    "network_input",
    "select_kept_slices",
    "unmap_values",
]

FloatArray = npt.NDArray[np.floating]

#: Denominator of the mapping, log(1 + ε) − log(ε).
_LOG_RANGE = float(np.log1p(1.0 / EPSILON))


def _working_dtype(array: np.ndarray) -> np.dtype:
    """float64 stays float64; everything else is computed in float32."""
    return np.dtype(np.float64) if array.dtype == np.float64 else np.dtype(np.float32)


def _channel_scale(ndim: int, channel_axis: int, dtype: np.dtype) -> np.ndarray:
    shape = [1] * ndim
    shape[channel_axis] = N_CHANNELS
    return MERL_COLOR_SCALE.astype(dtype).reshape(shape)


def map_values(values: npt.ArrayLike, *, channel_axis: int = 0) -> FloatArray:
    """Log-map stored MERL values (paper, eq. 1).

    Parameters
    ----------
    values : array_like
        Stored MERL values, ≥ 0 for valid entries; negative (unmeasured)
        entries map to 0 and should be masked by the caller. The axis
        ``channel_axis`` has length 3 (R, G, B).
    channel_axis : int, default 0
        Axis holding the colour channels.

    Returns
    -------
    ndarray
        Mapped values, ≥ 0 (a reflectance of 1/sr maps to 1; the stored
        value 1e6 maps to at most 2.52). float64 input gives float64;
        float16 and float32 input give float32. Finite for finite input.
    """
    array = np.asarray(values)
    if array.shape[channel_axis] != N_CHANNELS:
        raise ValueError(f"axis {channel_axis} must hold {N_CHANNELS} channels, got shape {array.shape}")
    dtype = _working_dtype(array)
    scale = _channel_scale(array.ndim, channel_axis, dtype) / dtype.type(EPSILON)
    positive = np.maximum(array.astype(dtype, copy=False), dtype.type(0))
    return np.log1p(positive * scale) / dtype.type(_LOG_RANGE)


def unmap_values(mapped: npt.ArrayLike, *, channel_axis: int = 0) -> FloatArray:
    """Exact inverse of :func:`map_values`, clamped to the mapped domain.

    Parameters
    ----------
    mapped : array_like
        Mapped values; clamped to ``[0, MAPPED_MAX]`` first (NaN becomes 0),
        so any decoder output gives a finite, non-negative table.
    channel_axis : int, default 0
        Axis holding the colour channels.

    Returns
    -------
    ndarray
        Stored MERL values, in [0, about 1.6e11]. float64 input gives
        float64; float16 and float32 input give float32.
    """
    array = np.asarray(mapped)
    if array.shape[channel_axis] != N_CHANNELS:
        raise ValueError(f"axis {channel_axis} must hold {N_CHANNELS} channels, got shape {array.shape}")
    dtype = _working_dtype(array)
    clamped = np.nan_to_num(np.clip(array.astype(dtype, copy=False), 0, MAPPED_MAX), nan=0.0)
    scale = dtype.type(EPSILON) / _channel_scale(array.ndim, channel_axis, dtype)
    return np.expm1(clamped * dtype.type(_LOG_RANGE)) * scale


def select_kept_slices(table: npt.ArrayLike) -> np.ndarray:
    """The 21 kept φd slices of a table.

    Parameters
    ----------
    table : array_like, shape (..., 180)
        Anything whose last axis is φd, e.g. a (3, 90, 90, 180) table.

    Returns
    -------
    ndarray, shape (..., 21)
        Slices :data:`~brdfcodec.conventions.KEPT_PHI_D_SLICES`, in order.
    """
    array = np.asarray(table)
    if array.shape[-1] != N_PHI_D:
        raise ValueError(f"last axis must be φd with {N_PHI_D} bins, got shape {array.shape}")
    return array[..., list(KEPT_PHI_D_SLICES)]


def network_input(kept: npt.ArrayLike) -> np.ndarray:
    """Rearrange kept slices ``(3, 90, 90, 21)`` to the network layout ``(63, 90, 90)``.

    Channel ``k`` of the result is colour ``k // 21`` at kept slice ``k % 21``;
    rows are θh bins, columns θd bins.
    """
    array = np.asarray(kept)
    expected = (N_CHANNELS, *TABLE_SHAPE[1:3], N_KEPT_SLICES)
    if array.shape[-4:] != expected:
        raise ValueError(f"expected kept slices of shape (..., {expected}), got {array.shape}")
    lead = array.shape[:-4]
    moved = np.moveaxis(array, -1, -3)  # (..., 3, 21, 90, 90)
    return np.ascontiguousarray(moved.reshape(*lead, *NETWORK_INPUT_SHAPE))


def from_network_input(network: npt.ArrayLike) -> np.ndarray:
    """Inverse of :func:`network_input`: ``(..., 63, 90, 90)`` to ``(..., 3, 90, 90, 21)``."""
    array = np.asarray(network)
    if array.shape[-3:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"expected network layout (..., {NETWORK_INPUT_SHAPE}), got {array.shape}")
    lead = array.shape[:-3]
    split = array.reshape(*lead, N_CHANNELS, N_KEPT_SLICES, *NETWORK_INPUT_SHAPE[1:])
    return np.moveaxis(split, -3, -1)


@functools.cache
def _interpolation_plan() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each φd bin: left kept slot, right kept slot, weight of the right one."""
    kept = np.asarray(KEPT_PHI_D_SLICES)
    phi = np.arange(N_PHI_D)
    right = np.clip(np.searchsorted(kept, phi, side="right"), 1, len(kept) - 1)
    left = right - 1
    weight = (phi - kept[left]) / (kept[right] - kept[left])
    on_kept = np.isin(phi, kept)  # exact copies, no arithmetic
    left = np.where(on_kept, np.searchsorted(kept, phi), left)
    right = np.where(on_kept, left, right)
    weight = np.where(on_kept, 0.0, weight)
    for array in (left, right, weight):
        array.setflags(write=False)
    return left, right, weight


def interpolate_slices(kept: npt.ArrayLike) -> np.ndarray:
    """Linear interpolation from the 21 kept φd slices back to 180.

    Parameters
    ----------
    kept : array_like, shape (..., 21)
        Values at the kept φd bins, last axis in the order of
        :data:`~brdfcodec.conventions.KEPT_PHI_D_SLICES`.

    Returns
    -------
    ndarray, shape (..., 180)
        Bin p between kept bins a ≤ p ≤ b gets
        ``(1 − t)·v[a] + t·v[b]`` with ``t = (p − a) / (b − a)``; kept bins are
        copied exactly. Same dtype as the input (float32 for integer input).
    """
    array = np.asarray(kept)
    if array.shape[-1] != N_KEPT_SLICES:
        raise ValueError(f"last axis must hold the {N_KEPT_SLICES} kept slices, got shape {array.shape}")
    if not np.issubdtype(array.dtype, np.floating):
        array = array.astype(np.float32)
    left, right, weight = _interpolation_plan()
    w = weight.astype(array.dtype)
    out = array[..., left] * (1 - w) + array[..., right] * w
    exact = weight == 0
    out[..., exact] = array[..., left[exact]]
    return out


def kept_slots_for_bins(phi_d_bins: Sequence[int]) -> tuple[int, ...]:
    """Positions (0–20) of the kept slices that the interpolation of the given φd bins reads, sorted."""
    left, right, _ = _interpolation_plan()
    bins = np.asarray(list(phi_d_bins), dtype=np.int64)
    if bins.size == 0 or bins.min() < 0 or bins.max() >= N_PHI_D:
        raise ValueError(f"phi_d_bins must be a non-empty sequence of bins in [0, {N_PHI_D}), got {phi_d_bins}")
    return tuple(int(v) for v in np.union1d(left[bins], right[bins]))


@functools.cache
def _unmapping_matrix(phi_d_bins: tuple[int, ...]) -> np.ndarray:
    """(21, K) float32 matrix: interpolation weights to the chosen bins, times the mapping's log range."""
    left, right, weight = _interpolation_plan()
    bins = np.asarray(phi_d_bins)
    matrix = np.zeros((N_KEPT_SLICES, len(bins)), dtype=np.float64)
    columns = np.arange(len(bins))
    matrix[left[bins], columns] += 1.0 - weight[bins]
    matrix[right[bins], columns] += weight[bins]
    out = (matrix * _LOG_RANGE).astype(np.float32)
    out.setflags(write=False)
    return out


def table_from_network_output(
    mapped: npt.ArrayLike, *, phi_d_bins: Sequence[int] | None = None
) -> npt.NDArray[np.float32]:
    """Full table (or chosen φd bins) in stored units from mapped network slices.

    Parameters
    ----------
    mapped : array_like, shape (..., 63, 90, 90)
        Mapped values at the kept slices in the network layout (a decoder's
        output); clamped to [0, MAPPED_MAX] first (NaN becomes 0).
    phi_d_bins : sequence of int, optional
        φd bins to produce, each in [0, 180); all 180 by default. One bin
        costs 1/180 of the full table.

    Returns
    -------
    ndarray of float32, shape (..., 3, 90, 90, K)
        Stored MERL values, finite and ≥ 0: the slices are interpolated in the
        mapped domain (``spec/conventions.md`` §7), then unmapped (§4). Both
        steps are one product with a (21, K) weight matrix followed by
        ``expm1`` and the channel scale; a kept bin has weight exactly 1, so
        it equals :func:`unmap_values` of the decoder's slice up to float32
        rounding of the log range.
    """
    bins = tuple(range(N_PHI_D)) if phi_d_bins is None else tuple(int(b) for b in phi_d_bins)
    if not bins or min(bins) < 0 or max(bins) >= N_PHI_D:
        raise ValueError(f"phi_d_bins must be a non-empty sequence of bins in [0, {N_PHI_D}), got {phi_d_bins}")
    array = np.asarray(mapped)
    if array.shape[-3:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"mapped must have shape (..., {', '.join(map(str, NETWORK_INPUT_SHAPE))}), got {array.shape}")
    lead = array.shape[:-3]
    clamped = np.nan_to_num(np.clip(array.astype(np.float32, copy=False), 0.0, MAPPED_MAX), nan=0.0)
    kept = clamped.reshape(*lead, N_CHANNELS, N_KEPT_SLICES, *NETWORK_INPUT_SHAPE[1:])
    kept = np.moveaxis(kept, -3, -1)  # (..., 3, 90, 90, 21)
    table = np.matmul(kept, _unmapping_matrix(bins))
    np.expm1(table, out=table)
    table *= (EPSILON / MERL_COLOR_SCALE).astype(np.float32).reshape(N_CHANNELS, 1, 1, 1)
    return table
