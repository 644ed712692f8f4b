"""The highlight guard: an edited material's highlight never darkens towards its centre
(``spec/bvae-format.md`` §6 step 6; issue 41).

A measured isotropic BRDF peaks at the half vector: near it (θh bins 0–20 of the
MERL grid, θh below 4.4°) the reflectance does not fall towards the centre. A
latent edit can break that: a traversal may pull the decoder's output at the
centre below its surroundings, or to the floor of the mapped domain, a black pit
in the highlight (``brdfcodec.edit.plausibility``: *inverted*, *holes* and *pits*).
Decoders therefore raise, in the decode of an edited record, each value m of
θh bin i < :data:`GUARD_THETA_H_BINS` to at least ``R − min(τ, R / 2)``, where R is
the largest value of the same cell (colour, kept φd slot, θd bin) at θh bins i + 1
to 20 above the horizon and τ :data:`HIGHLIGHT_TOLERANCE`; values below the
horizon are neither raised nor counted. Values already that high, every value beyond bin 20
and every record that is not an edit are unchanged. The guarded profile then
falls by at most τ towards the centre (a *pit* needs more than 0.1), and a lit
surrounding keeps a lit centre.

The guard acts on the mapped kept slices after the clamp (step 2), before the
energy bound (step 5) and the interpolation to 180 φd slices: a linear
interpolation of guarded slices is guarded, and the energy bound's factor,
monotone in the mapped value and shrinking differences, keeps it so.

Examples
--------
>>> import numpy as np
>>> mapped = np.full((63, 90, 90), 0.5, dtype=np.float32)
>>> mapped[:, 0:8, 10] = 0.0  # a black pit at the centre of every colour's and slot's highlight, θd bin 10
>>> guarded = guard_highlights_mapped(mapped)
>>> round(float(guarded[0, 0, 10]), 6), float(guarded[0, 8, 10]), bool((guarded[:, 21:] == mapped[:, 21:]).all())
(0.45, 0.5, True)
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_CHANNELS, N_KEPT_SLICES, N_THETA_D, N_THETA_H, NETWORK_INPUT_SHAPE

__all__ = [
    "GUARD_THETA_H_BINS",
    "HIGHLIGHT_TOLERANCE",
    "NEAR_THETA_H_BINS",
    "OFF_THETA_H_BINS",
    "cell_valid_mask",
    "guard_highlights_mapped",
]

#: θh bins of the near-specular peak (they span θh < 0.045°).
NEAR_THETA_H_BINS: tuple[int, ...] = (0, 1)
#: θh bins of the off-specular flank (they span θh 0.18–0.54°).
OFF_THETA_H_BINS: tuple[int, ...] = (4, 5, 6)
#: τ of the guard, mapped units: how far a guarded highlight may fall towards its centre.
HIGHLIGHT_TOLERANCE = 0.05
#: θh bins the guard and the *pits* check look at: 0 to 20 (θh below 4.4°).
GUARD_THETA_H_BINS = 21


@functools.cache
def cell_valid_mask() -> npt.NDArray[np.bool_]:
    """(21, 90): kept slot × θd bin cells whose near and off θh entries are all above the horizon."""
    from brdfcodec.representation.mask import kept_slice_horizon_mask

    rows = kept_slice_horizon_mask()[list(NEAR_THETA_H_BINS + OFF_THETA_H_BINS)]  # (5, θd, slot)
    valid = np.ascontiguousarray(rows.all(axis=0).T)
    valid.setflags(write=False)
    return valid


@functools.cache
def window_valid_mask() -> npt.NDArray[np.bool_]:
    """(21 slots, 21 θh bins 0–20, 90 θd): the entries of the guard's window that lie above the horizon."""
    from brdfcodec.representation.mask import kept_slice_horizon_mask

    valid = np.ascontiguousarray(np.moveaxis(kept_slice_horizon_mask()[:GUARD_THETA_H_BINS], -1, 0))
    valid.setflags(write=False)
    return valid


def _blocks(array: np.ndarray) -> np.ndarray:
    if array.shape[-3:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"expected mapped slices of shape (..., {NETWORK_INPUT_SHAPE}), got {array.shape}")
    return array.reshape(*array.shape[:-3], N_CHANNELS, N_KEPT_SLICES, N_THETA_H, N_THETA_D)


def outer_maximum(mapped: npt.ArrayLike) -> np.ndarray:
    """R per θh bin i < 20: the largest value of the same cell at θh bins i + 1 to 20 above the horizon.

    Parameters
    ----------
    mapped : array_like, shape (..., 63, 90, 90)

    Returns
    -------
    ndarray, shape (..., 3, 21, 20, 90)
        Colour, kept slot, θh bin 0–19, θd bin; mapped units; −inf where no bin beyond i is above the horizon.
    """
    window = _blocks(np.asarray(mapped))[..., :GUARD_THETA_H_BINS, :]
    window = np.where(window_valid_mask(), window, -np.inf)
    outer = np.maximum.accumulate(window[..., ::-1, :], axis=-2)[..., ::-1, :]  # max over j ≥ i
    return outer[..., 1:, :]


def guard_highlights_mapped(mapped: npt.ArrayLike, tolerance: float = HIGHLIGHT_TOLERANCE) -> np.ndarray:
    """Raise the values of a highlight that fall towards its centre (see the module docstring).

    Parameters
    ----------
    mapped : array_like, shape (..., 63, 90, 90)
        Mapped kept slices in the network layout, finite (clamped to the mapped domain).
    tolerance : float, default :data:`HIGHLIGHT_TOLERANCE`
        τ ≥ 0, mapped units.

    Returns
    -------
    ndarray
        A guarded copy, same shape and floating dtype.
    """
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"tolerance must be finite and ≥ 0, got {tolerance}")
    out = np.array(mapped, copy=True)
    blocks = _blocks(out)
    outer = outer_maximum(out)  # (..., 3, 21, 20, θd), of the values before the guard
    lit = np.isfinite(outer) & window_valid_mask()[:, :-1, :]
    with np.errstate(invalid="ignore"):
        floor = np.where(lit, outer - np.minimum(tolerance, outer / 2), -np.inf).astype(out.dtype, copy=False)
    inner = slice(0, GUARD_THETA_H_BINS - 1)
    blocks[..., inner, :] = np.maximum(blocks[..., inner, :], floor)
    return out
