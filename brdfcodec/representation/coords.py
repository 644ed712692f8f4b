"""Directions, Rusinkiewicz half/difference angles and MERL bins.

Directions are unit vectors in the local shading frame (z is the surface
normal), as arrays whose last axis has length 3. Angles are in radians.
The MERL bins and their representative angles are defined in
``spec/conventions.md``:

========  =====================================  ==============================
angle     bin index (before clamping)            representative angle of bin i
========  =====================================  ==============================
θh        ⌊90 · sqrt(θh / (π/2))⌋                (i / 90)² · π/2
θd        ⌊90 · θd / (π/2)⌋                      i / 90 · π/2
φd        ⌊180 · (φd mod π) / π⌋                 i / 180 · π
========  =====================================  ==============================

A representative angle is the lower edge of its bin, as in MERL's reader.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import BIN_TOLERANCE, N_PHI_D, N_THETA_D, N_THETA_H

__all__ = [
    "directions_from_half_diff",
    "fold_phi_d",
    "grid_angles",
    "grid_direction_cosines",
    "half_diff_from_directions",
    "phi_d_coordinate",
    "phi_d_from_index",
    "phi_d_index",
    "theta_d_coordinate",
    "theta_d_from_index",
    "theta_d_index",
    "theta_h_coordinate",
    "theta_h_from_index",
    "theta_h_index",
]

ArrayLike = npt.ArrayLike
FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

_HALF_PI = np.pi / 2


def _normalize(v: FloatArray) -> FloatArray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(norm > 0, norm, 1.0)


def _elevation(v: FloatArray) -> FloatArray:
    """Angle from +z, accurate near 0 and π (unlike arccos of z)."""
    return np.arctan2(np.hypot(v[..., 0], v[..., 1]), v[..., 2])


def _rotate_z(v: FloatArray, angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([x * c - y * s, x * s + y * c, z], axis=-1)


def _rotate_y(v: FloatArray, angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([x * c + z * s, y, -x * s + z * c], axis=-1)


def half_diff_from_directions(
    wi: ArrayLike, wo: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Rusinkiewicz angles of direction pairs.

    Parameters
    ----------
    wi, wo : array_like, shape (..., 3)
        Incoming and outgoing directions in the shading frame (normalised
        here; need not be unit length). Broadcast against each other.

    Returns
    -------
    theta_h : ndarray
        Half-vector elevation, in [0, π].
    theta_d : ndarray
        Difference-vector elevation, in [0, π].
    phi_d : ndarray
        Difference-vector azimuth, in (-π, π]; not folded.
    phi_h : ndarray
        Half-vector azimuth, in (-π, π]; irrelevant for isotropic BRDFs.

    Notes
    -----
    ``h = normalize(wi + wo)``; ``d`` is ``wi`` rotated by ``-φh`` about z
    and then by ``-θh`` about y. Exchanging ``wi`` and ``wo`` leaves θh and
    θd unchanged and adds π to φd (reciprocity).
    """
    wi_arr = _normalize(np.asarray(wi, dtype=np.float64))
    wo_arr = _normalize(np.asarray(wo, dtype=np.float64))
    wi_arr, wo_arr = np.broadcast_arrays(wi_arr, wo_arr)
    half = _normalize(wi_arr + wo_arr)
    theta_h = _elevation(half)
    phi_h = np.arctan2(half[..., 1], half[..., 0])
    diff = _rotate_y(_rotate_z(wi_arr, -phi_h), -theta_h)
    theta_d = _elevation(diff)
    phi_d = np.arctan2(diff[..., 1], diff[..., 0])
    return theta_h, theta_d, phi_d, phi_h


def directions_from_half_diff(
    theta_h: ArrayLike,
    theta_d: ArrayLike,
    phi_d: ArrayLike,
    phi_h: ArrayLike = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """Direction pair of given Rusinkiewicz angles (inverse of :func:`half_diff_from_directions`).

    Parameters
    ----------
    theta_h, theta_d, phi_d : array_like
        Angles in radians, broadcast together.
    phi_h : array_like, default 0
        Half-vector azimuth in radians.

    Returns
    -------
    wi, wo : ndarray, shape (..., 3)
        Unit incoming and outgoing directions.
    """
    th, td, pd, ph = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d, phi_h))
    )
    diff = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], axis=-1)
    half = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    wi = _rotate_z(_rotate_y(diff, th), ph)
    wo = 2.0 * np.sum(wi * half, axis=-1, keepdims=True) * half - wi
    return wi, wo


def fold_phi_d(phi_d: ArrayLike) -> FloatArray:
    """Fold φd into [0, π) by reciprocity (φd and φd + π are the same entry).

    Parameters
    ----------
    phi_d : array_like
        Any angle in radians.

    Returns
    -------
    ndarray
        ``phi_d mod π``, in [0, π).
    """
    folded = np.mod(np.asarray(phi_d, dtype=np.float64), np.pi)
    return np.where(folded >= np.pi, 0.0, folded)  # mod can round up to π itself


def theta_h_coordinate(theta_h: ArrayLike) -> FloatArray:
    """Continuous θh bin coordinate ``90 · sqrt(θh / (π/2))`` (bin i spans [i, i + 1))."""
    th = np.clip(np.asarray(theta_h, dtype=np.float64), 0.0, None)
    return N_THETA_H * np.sqrt(th / _HALF_PI)


def theta_d_coordinate(theta_d: ArrayLike) -> FloatArray:
    """Continuous θd bin coordinate ``90 · θd / (π/2)``."""
    return N_THETA_D * np.clip(np.asarray(theta_d, dtype=np.float64), 0.0, None) / _HALF_PI


def phi_d_coordinate(phi_d: ArrayLike) -> FloatArray:
    """Continuous φd bin coordinate ``180 · (φd mod π) / π``, in [0, 180)."""
    return N_PHI_D * fold_phi_d(phi_d) / np.pi


def _bin(coordinate: FloatArray, n: int) -> IntArray:
    index = np.floor(coordinate + BIN_TOLERANCE).astype(np.intp)
    return np.clip(index, 0, n - 1)


def theta_h_index(theta_h: ArrayLike) -> IntArray:
    """MERL θh bin of an angle (non-linear), clamped to [0, 89].

    Parameters
    ----------
    theta_h : array_like
        Half-vector elevation in radians; values past π/2 land in bin 89.

    Returns
    -------
    ndarray of intp
    """
    return _bin(theta_h_coordinate(theta_h), N_THETA_H)


def theta_d_index(theta_d: ArrayLike) -> IntArray:
    """MERL θd bin of an angle (linear), clamped to [0, 89]."""
    return _bin(theta_d_coordinate(theta_d), N_THETA_D)


def phi_d_index(phi_d: ArrayLike) -> IntArray:
    """MERL φd bin of an angle, after folding by reciprocity, in [0, 179]."""
    return np.mod(_bin(phi_d_coordinate(phi_d), N_PHI_D + 1), N_PHI_D)


def theta_h_from_index(index: ArrayLike) -> FloatArray:
    """Representative θh (radians) of bin ``index``: ``(index / 90)² · π/2``."""
    i = np.asarray(index, dtype=np.float64)
    return (i / N_THETA_H) ** 2 * _HALF_PI


def theta_d_from_index(index: ArrayLike) -> FloatArray:
    """Representative θd (radians) of bin ``index``: ``index / 90 · π/2``."""
    return np.asarray(index, dtype=np.float64) / N_THETA_D * _HALF_PI


def phi_d_from_index(index: ArrayLike) -> FloatArray:
    """Representative φd (radians) of bin ``index``: ``index / 180 · π``."""
    return np.asarray(index, dtype=np.float64) / N_PHI_D * np.pi


def grid_angles(phi_d_slices: ArrayLike | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Representative angles of the MERL grid, broadcast to ``(90, 90, n_φd)``.

    Parameters
    ----------
    phi_d_slices : array_like of int, optional
        φd bins to include; all 180 by default.

    Returns
    -------
    theta_h, theta_d, phi_d : ndarray, shape (90, 90, n_φd)
        Angles in radians, indexed ``[θh bin, θd bin, φd bin]``.
    """
    th, td, pd = _grid_axes(phi_d_slices)
    shape = (N_THETA_H, N_THETA_D, pd.size)
    return np.broadcast_to(th, shape), np.broadcast_to(td, shape), np.broadcast_to(pd, shape)


def _grid_axes(phi_d_slices: ArrayLike | None) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Representative θh, θd, φd of the grid as (90, 1, 1), (1, 90, 1) and (1, 1, n_φd) arrays."""
    slices = np.arange(N_PHI_D) if phi_d_slices is None else np.asarray(phi_d_slices)
    th = theta_h_from_index(np.arange(N_THETA_H))[:, None, None]
    td = theta_d_from_index(np.arange(N_THETA_D))[None, :, None]
    return th, td, phi_d_from_index(slices)[None, None, :]


def grid_direction_cosines(phi_d_slices: ArrayLike | None = None) -> tuple[FloatArray, FloatArray]:
    """z components (cos θ) of the incoming and outgoing directions of the MERL grid.

    The same values as ``directions_from_half_diff(*grid_angles(phi_d_slices))``
    (φh = 0), computed by broadcasting the three 1-D angle axes instead of
    building the (90, 90, n_φd, 3) direction arrays: much faster on the
    full grid, which the horizon mask and the cosine-weighted metric need in
    every process.

    Parameters
    ----------
    phi_d_slices : array_like of int, optional
        As for :func:`grid_angles`.

    Returns
    -------
    cos_in, cos_out : ndarray of float64, shape (90, 90, n_φd)
        Indexed like :func:`grid_angles`' arrays; in [-1, 1].
    """
    th, td, pd = _grid_axes(phi_d_slices)
    # diff = (sin θd cos φd, ·, cos θd); wi = R_y(θh) diff; wo = 2 (wi·h) h − wi with h = (sin θh, 0, cos θh).
    diff_x, diff_z = np.sin(td) * np.cos(pd), np.cos(td)
    sin_h, cos_h = np.sin(th), np.cos(th)
    wi_x = diff_x * cos_h + diff_z * sin_h
    cos_in = -diff_x * sin_h + diff_z * cos_h
    wi_dot_h = wi_x * sin_h + cos_in * cos_h
    cos_out = 2.0 * wi_dot_h * cos_h - cos_in
    return cos_in, cos_out  # (90, 1, 1) × (1, 90, n_φd) terms: already full-size arrays
