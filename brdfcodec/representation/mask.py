"""Validity of table entries: above the horizon, and measured.

An entry of a MERL table is *valid* when (a) both its incoming and outgoing
directions, taken at the bin's representative angles, are above the horizon
(cosine > :data:`~brdfcodec.conventions.HORIZON_COS_MIN`), and (b) its
stored value is finite and not negative (MERL stores unmeasured entries as
negative numbers). Losses and metrics use valid entries only.
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import HORIZON_COS_MIN, KEPT_PHI_D_SLICES, TABLE_SHAPE
from brdfcodec.representation.coords import grid_direction_cosines

__all__ = ["horizon_mask", "kept_slice_horizon_mask", "validity_mask"]

BoolArray = npt.NDArray[np.bool_]


@functools.cache
def horizon_mask() -> BoolArray:
    """Entries of the 90×90×180 grid whose directions are both above the horizon.

    Returns
    -------
    ndarray of bool, shape (90, 90, 180)
        Indexed ``[θh, θd, φd]``; read-only and shared between calls.
    """
    cos_in, cos_out = grid_direction_cosines()
    mask = (cos_in > HORIZON_COS_MIN) & (cos_out > HORIZON_COS_MIN)
    mask.setflags(write=False)
    return mask


@functools.cache
def kept_slice_horizon_mask() -> BoolArray:
    """:func:`horizon_mask` restricted to the 21 kept φd slices, shape (90, 90, 21)."""
    mask = np.ascontiguousarray(horizon_mask()[:, :, list(KEPT_PHI_D_SLICES)])
    mask.setflags(write=False)
    return mask


def validity_mask(values: npt.ArrayLike) -> BoolArray:
    """Valid entries of a table in MERL layout.

    Parameters
    ----------
    values : array_like, shape (3, 90, 90, 180)
        Stored (or physical) values, indexed ``[channel, θh, θd, φd]``.

    Returns
    -------
    ndarray of bool, shape (3, 90, 90, 180)
        True where the entry is above the horizon, finite and not negative.
    """
    table = np.asarray(values)
    if table.shape != TABLE_SHAPE:
        raise ValueError(f"expected a table of shape {TABLE_SHAPE}, got {table.shape}")
    with np.errstate(invalid="ignore"):
        measured = np.isfinite(table) & (table >= 0)
    return measured & horizon_mask()[None]
