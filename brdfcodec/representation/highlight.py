"""The highlight's profile near the half vector: which θh bins and cells the plausibility checks compare
(``brdfcodec.edit.plausibility``: *inverted*, *holes*, *pits*; issue 41).

A measured isotropic BRDF peaks at the half vector: near it (θh bins 0–20 of the
MERL grid, θh below 4.4°) the reflectance does not fall towards the centre. A
latent edit can break that: a traversal may pull the decoder's output at the
centre below its surroundings, or to the floor of the mapped domain, a black pit
in the highlight. :func:`outer_maximum` gives, per θh bin, the largest value
beyond it in that window, from which the checks measure such a fall.

Examples
--------
>>> import numpy as np
>>> mapped = np.full((63, 90, 90), 0.5, dtype=np.float32)
>>> mapped[:, 0:8, 10] = 0.0  # a black pit at the centre of every colour's and slot's highlight, θd bin 10
>>> outer = outer_maximum(mapped)  # colour, kept slot, θh bin 0–19, θd bin
>>> outer.shape, float(outer[0, 0, 0, 10]), float(outer[0, 0, 0, 11])
((3, 21, 20, 90), 0.5, 0.5)
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_CHANNELS, N_KEPT_SLICES, N_THETA_D, N_THETA_H, NETWORK_INPUT_SHAPE

__all__ = [
    "PIT_THETA_H_BINS",
    "NEAR_THETA_H_BINS",
    "OFF_THETA_H_BINS",
    "cell_valid_mask",
    "outer_maximum",
    "window_valid_mask",
]

#: θh bins of the near-specular peak (they span θh < 0.045°).
NEAR_THETA_H_BINS: tuple[int, ...] = (0, 1)
#: θh bins of the off-specular flank (they span θh 0.18–0.54°).
OFF_THETA_H_BINS: tuple[int, ...] = (4, 5, 6)
#: θh bins the *pits* check looks at: 0 to 20 (θh below 4.4°).
PIT_THETA_H_BINS = 21


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
    """(21 slots, 21 θh bins 0–20, 90 θd): the entries of the pits check's window that lie above the horizon."""
    from brdfcodec.representation.mask import kept_slice_horizon_mask

    valid = np.ascontiguousarray(np.moveaxis(kept_slice_horizon_mask()[:PIT_THETA_H_BINS], -1, 0))
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
    window = _blocks(np.asarray(mapped))[..., :PIT_THETA_H_BINS, :]
    window = np.where(window_valid_mask(), window, -np.inf)
    outer = np.maximum.accumulate(window[..., ::-1, :], axis=-2)[..., ::-1, :]  # max over j ≥ i
    return outer[..., 1:, :]
