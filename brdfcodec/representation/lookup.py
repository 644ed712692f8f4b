"""Vectorised evaluation of a MERL-layout table at direction pairs."""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import HORIZON_COS_MIN, N_PHI_D, N_THETA_D, N_THETA_H, TABLE_SHAPE
from brdfcodec.representation.coords import (
    half_diff_from_directions,
    phi_d_coordinate,
    phi_d_index,
    theta_d_coordinate,
    theta_d_index,
    theta_h_coordinate,
    theta_h_index,
)

__all__ = ["lookup"]

LookupMode = Literal["nearest", "trilinear"]


def _axis_corners(coordinate: np.ndarray, n: int, periodic: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lower and upper neighbouring bins and the weight of the upper one."""
    if periodic:
        lower = np.floor(coordinate).astype(np.intp)
        frac = coordinate - lower
        return np.mod(lower, n), np.mod(lower + 1, n), frac
    clamped = np.clip(coordinate, 0.0, n - 1.0)
    lower = np.minimum(np.floor(clamped).astype(np.intp), n - 2)
    return lower, lower + 1, clamped - lower


def _directions(values: npt.ArrayLike, label: str) -> np.ndarray:
    """Direction vectors as float64 (..., 3): finite and non-zero (any length; they are normalised)."""
    array = np.asarray(values, dtype=np.float64)
    if array.ndim == 0 or array.shape[-1] != 3:
        raise ValueError(f"{label} must hold 3-vectors, shape (..., 3), got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{label} holds NaN or infinite components")
    if not (np.abs(array) > 0).any(axis=-1).all():
        raise ValueError(f"{label} holds zero vectors (a direction needs a length > 0)")
    return array


def lookup(
    table: npt.ArrayLike,
    wi: npt.ArrayLike,
    wo: npt.ArrayLike,
    *,
    mode: LookupMode = "nearest",
    mask: npt.ArrayLike | None = None,
) -> npt.NDArray[np.float64]:
    """Evaluate a table at direction pairs.

    Parameters
    ----------
    table : array_like, shape (3, 90, 90, 180)
        Values in MERL layout, in whatever units the caller wants back
        (usually physical reflectance, 1/sr).
    wi, wo : array_like, shape (..., 3)
        Incoming and outgoing directions in the shading frame (z = normal,
        pointing away from the surface), broadcast together; any finite,
        non-zero length (they are normalised). Exchanging them gives the
        same result.
    mode : {"nearest", "trilinear"}, default "nearest"
        ``nearest`` returns the entry of the bin holding the angles (as
        MERL's reader does). ``trilinear`` interpolates between the
        representative angles of neighbouring bins in the bin coordinates
        (θh in its square-root coordinate); φd wraps around π.
    mask : array_like of bool, shape (3, 90, 90, 180), optional
        Valid entries. Invalid entries never contribute: ``nearest`` returns
        0 for them, ``trilinear`` renormalises the weights of the valid
        neighbours (0 if there are none). By default every entry is valid.

    Returns
    -------
    ndarray of float64, shape (..., 3)
        RGB values. Pairs with either direction at or below the horizon
        give 0.

    Raises
    ------
    ValueError
        A direction array whose last axis is not 3, that holds NaN, infinite
        or zero vectors, or that does not broadcast with the other.
    """
    values = np.asarray(table)
    if values.dtype not in (np.float32, np.float64):  # float32 tables (decoded materials) are read as they are
        values = values.astype(np.float64)
    if values.shape != TABLE_SHAPE:
        raise ValueError(f"table must have shape {TABLE_SHAPE}, got {values.shape}")
    if mode not in ("nearest", "trilinear"):
        raise ValueError(f"mode must be 'nearest' or 'trilinear', got {mode!r}")
    valid = None if mask is None else np.asarray(mask, dtype=bool)
    if valid is not None and valid.shape != TABLE_SHAPE:
        raise ValueError(f"mask must have shape {TABLE_SHAPE}, got {valid.shape}")
    wi_arr = _directions(wi, "wi")
    wo_arr = _directions(wo, "wo")
    try:
        np.broadcast_shapes(wi_arr.shape, wo_arr.shape)
    except ValueError:
        raise ValueError(f"wi and wo do not broadcast together: shapes {wi_arr.shape} and {wo_arr.shape}") from None
    theta_h, theta_d, phi_d, _ = half_diff_from_directions(wi_arr, wo_arr)
    wi_b, wo_b = np.broadcast_arrays(wi_arr, wo_arr)
    above = (wi_b[..., 2] > HORIZON_COS_MIN) & (wo_b[..., 2] > HORIZON_COS_MIN)
    # Channels last for gathering: (90, 90, 180, 3).
    channels_last = np.moveaxis(values, 0, -1)
    valid_last = None if valid is None else np.moveaxis(valid, 0, -1)

    if mode == "nearest":
        index = (theta_h_index(theta_h), theta_d_index(theta_d), phi_d_index(phi_d))
        result = channels_last[index]
        if valid_last is not None:
            result = np.where(valid_last[index], result, 0.0)
    else:
        corners_h = _axis_corners(theta_h_coordinate(theta_h), N_THETA_H, periodic=False)
        corners_d = _axis_corners(theta_d_coordinate(theta_d), N_THETA_D, periodic=False)
        corners_p = _axis_corners(phi_d_coordinate(phi_d), N_PHI_D, periodic=True)
        total = np.zeros((*theta_h.shape, 3))
        weight_sum = np.zeros((*theta_h.shape, 3))
        for ih, wh in ((corners_h[0], 1 - corners_h[2]), (corners_h[1], corners_h[2])):
            for id_, wd in ((corners_d[0], 1 - corners_d[2]), (corners_d[1], corners_d[2])):
                for ip, wp in ((corners_p[0], 1 - corners_p[2]), (corners_p[1], corners_p[2])):
                    weight = (wh * wd * wp)[..., None]
                    corner = channels_last[ih, id_, ip]
                    if valid_last is not None:
                        weight = np.where(valid_last[ih, id_, ip], weight, 0.0)
                    total += weight * np.where(weight > 0, corner, 0.0)
                    weight_sum += weight
        result = np.divide(total, weight_sum, out=np.zeros_like(total), where=weight_sum > 0)
    return np.where(above[..., None], result, 0.0)
