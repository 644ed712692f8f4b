"""Where each number sits: kept φd slices, the network's channel layout, and φd interpolation.

A table is ``[channel, θh, θd, φd]`` of shape (3, 90, 90, 180). The network
sees the 21 kept φd slices (:data:`~brdfcodec.conventions.KEPT_PHI_D_SLICES`)
as 63 channels of 90×90: channel ``k`` is colour ``k // 21`` at kept slot
``k % 21`` (:func:`network_channel`).

>>> network_channel(colour=1, slot=0)
21
>>> kept_slots_for_bins([0, 90])
(0, 10)
>>> validate_phi_d_bins(None)[:3], len(validate_phi_d_bins(None))
((0, 1, 2), 180)
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import (
    KEPT_PHI_D_SLICES,
    N_CHANNELS,
    N_KEPT_SLICES,
    N_PHI_D,
    NETWORK_INPUT_SHAPE,
    TABLE_SHAPE,
)

__all__ = [
    "BLUE_BLOCK",
    "GREEN_BLOCK",
    "RED_BLOCK",
    "from_network_layout",
    "interpolate_slices",
    "kept_slots_for_bins",
    "network_channel",
    "network_channels_for_slots",
    "to_network_layout",
    "select_kept_slices",
    "validate_phi_d_bins",
]

#: Channels of the network layout holding red, green and blue (21 kept slices each).
RED_BLOCK = slice(0, N_KEPT_SLICES)
GREEN_BLOCK = slice(N_KEPT_SLICES, 2 * N_KEPT_SLICES)
BLUE_BLOCK = slice(2 * N_KEPT_SLICES, 3 * N_KEPT_SLICES)


def network_channel(colour: int, slot: int) -> int:
    """Channel of the network layout that holds ``colour`` (0 R, 1 G, 2 B) at kept slot ``slot`` (0–20)."""
    if not (0 <= colour < N_CHANNELS and 0 <= slot < N_KEPT_SLICES):
        raise ValueError(f"colour must be in [0, {N_CHANNELS}) and slot in [0, {N_KEPT_SLICES}), got {colour}, {slot}")
    return colour * N_KEPT_SLICES + slot


def network_channels_for_slots(slots: Sequence[int], colours: Sequence[int] = (0, 1, 2)) -> list[int]:
    """Channels of the network layout for some colours at some kept slots, colour-major."""
    return [network_channel(c, s) for c in colours for s in slots]


def validate_phi_d_bins(phi_d_bins: Sequence[int] | None) -> tuple[int, ...]:
    """φd bins as a tuple of ints, all 180 for ``None``; the one check of a bin selection.

    Raises
    ------
    ValueError
        Empty, or a bin outside [0, 180).
    """
    if phi_d_bins is None:
        return tuple(range(N_PHI_D))
    bins = tuple(int(b) for b in phi_d_bins)
    if not bins or min(bins) < 0 or max(bins) >= N_PHI_D:
        raise ValueError(f"phi_d_bins must be a non-empty sequence of bins in [0, {N_PHI_D}), got {phi_d_bins}")
    return bins


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


def to_network_layout(kept: npt.ArrayLike) -> np.ndarray:
    """Rearrange kept slices ``(..., 3, 90, 90, 21)`` to the network layout ``(..., 63, 90, 90)``.

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


def from_network_layout(network: npt.ArrayLike) -> np.ndarray:
    """Inverse of :func:`to_network_layout`: ``(..., 63, 90, 90)`` to ``(..., 3, 90, 90, 21)`` (a view)."""
    array = np.asarray(network)
    if array.shape[-3:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"expected network layout (..., {NETWORK_INPUT_SHAPE}), got {array.shape}")
    lead = array.shape[:-3]
    split = array.reshape(*lead, N_CHANNELS, N_KEPT_SLICES, *NETWORK_INPUT_SHAPE[1:])
    return np.moveaxis(split, -3, -1)


@functools.cache
def interpolation_plan() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each φd bin: left kept slot, right kept slot, weight of the right one (read-only arrays)."""
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
    left, right, weight = interpolation_plan()
    w = weight.astype(array.dtype)
    out = array[..., left] * (1 - w) + array[..., right] * w
    exact = weight == 0
    out[..., exact] = array[..., left[exact]]
    return out


def kept_slots_for_bins(phi_d_bins: Sequence[int]) -> tuple[int, ...]:
    """Positions (0–20) of the kept slices that the interpolation of the given φd bins reads, sorted."""
    left, right, _ = interpolation_plan()
    bins = np.asarray(validate_phi_d_bins(phi_d_bins), dtype=np.int64)
    return tuple(int(v) for v in np.union1d(left[bins], right[bins]))
