"""The highlight guard: an edited material's specular peak is never darker than its flank
(``spec/bvae-format.md`` §6 step 6; issue 41).

A measured isotropic BRDF peaks at the half vector: within half a degree of it
(θh bins 0–1 against 4–6 of the MERL grid, 0.045° against 0.18–0.54°) the
reflectance does not fall towards the peak. A latent edit can break that — a
traversal may pull the decoder's output at the peak below its flank, or to the
floor of the mapped domain under a lit flank, a black pit in the highlight
(``brdfcodec.edit.plausibility``: *inverted* and *holes*). Decoders therefore
raise, in the decode of an edited record, each near-specular entry to at least
``f − min(τ, f / 2)``, where ``f`` is the largest flank value of its cell (colour,
kept φd slot, θd bin) and τ :data:`HIGHLIGHT_TOLERANCE`; cells with an entry
below the horizon are left alone. Entries already that high, every other entry
and every record that is not an edit are unchanged. The peak then falls at most
τ below its flank (an *inverted* cell needs more than 0.1), and a lit flank
keeps a lit peak.

The guard acts on the mapped kept slices after the clamp (step 2), before the
energy bound (step 5) and the interpolation to 180 φd slices: a linear
interpolation of guarded slices is guarded, and the energy bound's factor,
monotone in the mapped value and shrinking differences, keeps it so.

Examples
--------
>>> import numpy as np
>>> mapped = np.full((63, 90, 90), 0.5, dtype=np.float32)
>>> mapped[:, 0:2, 10] = 0.0  # a black pit at the peak of every colour and slot, θd bin 10
>>> guarded = guard_highlights_mapped(mapped)
>>> round(float(guarded[0, 0, 10]), 6), float(guarded[0, 2, 10]), bool((guarded[:, 2:] == mapped[:, 2:]).all())
(0.45, 0.5, True)
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_CHANNELS, N_KEPT_SLICES, N_THETA_D, N_THETA_H, NETWORK_INPUT_SHAPE

__all__ = [
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
#: τ of the guard, mapped units: how far below its flank a guarded peak may stay.
HIGHLIGHT_TOLERANCE = 0.05


@functools.cache
def cell_valid_mask() -> npt.NDArray[np.bool_]:
    """(21, 90): kept slot × θd bin cells whose near and off θh entries are all above the horizon."""
    from brdfcodec.representation.mask import kept_slice_horizon_mask

    rows = kept_slice_horizon_mask()[list(NEAR_THETA_H_BINS + OFF_THETA_H_BINS)]  # (5, θd, slot)
    valid = np.ascontiguousarray(rows.all(axis=0).T)
    valid.setflags(write=False)
    return valid


def guard_highlights_mapped(mapped: npt.ArrayLike, tolerance: float = HIGHLIGHT_TOLERANCE) -> np.ndarray:
    """Raise near-specular entries that fall below their flank (see the module docstring).

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
    if out.shape[-3:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"expected mapped slices of shape (..., {NETWORK_INPUT_SHAPE}), got {out.shape}")
    blocks = out.reshape(*out.shape[:-3], N_CHANNELS, N_KEPT_SLICES, N_THETA_H, N_THETA_D)
    near = list(NEAR_THETA_H_BINS)
    flank = blocks[..., list(OFF_THETA_H_BINS), :].max(axis=-2)  # (..., 3, 21, θd)
    floor = (flank - np.minimum(tolerance, flank / 2)).astype(out.dtype, copy=False)
    floor = np.where(cell_valid_mask(), floor, -np.inf)[..., None, :]  # (..., 3, 21, 1, θd)
    blocks[..., near, :] = np.maximum(blocks[..., near, :], floor)
    return out
