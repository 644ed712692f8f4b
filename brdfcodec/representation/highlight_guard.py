"""The highlight guard of edited records (``spec/bvae-format.md`` §6 step 6; issue 50, item 1).

A latent edit (a traversal, a mix, a graft) can pull the decoder's output at the centre of a highlight below
its surroundings: a dark dot where the half vector lies, a material no instrument would measure. The guard
is a decode-time step for edited records only (encoded materials decode as measured): in every column of
the mapped slices (colour, kept φd slot, θd bin), within the window of θh bins ``0 … W − 1``, no entry may
fall more than τ below the largest entry further out in the window,

.. math::

    g_i = \\max\\bigl(m_i,\\; \\max_{i < k < W,\\ k \\text{ above the horizon}} m_k - τ\\bigr),

a running maximum from the window's edge towards θh = 0, relaxed by τ (mapped units, ``spec/conventions.md``
§4). Entries below the horizon are neither read nor written. Because each raised entry stays at or below a
value further out, the running maximum of g equals that of m: the guard is idempotent, never raises an
entry above the column's own window maximum (so it stays in the mapped domain), and leaves a highlight that
already rises towards its centre (up to τ) bit for bit as it is. Columns are mapped-domain sequences of the
kept slices; the interpolation to the other φd bins is convex in the mapped domain, so the interpolated
columns satisfy the same bound.

Examples
--------
>>> import numpy as np
>>> mapped = np.full((63, 90, 90), 0.6, dtype=np.float32)
>>> mapped[:, :8, 10] = 0.1                 # a dark pit at the centre of every highlight at θd bin 10
>>> guarded = guard_highlight(mapped)
>>> round(float(guarded[0, 0, 10]), 4), round(float(guarded[0, 80, 10]), 4)  # 0.6 − τ in the window; beyond: as is
(0.55, 0.6)
>>> bool(np.array_equal(guard_highlight(guarded), guarded))  # idempotent
True
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_CHANNELS, N_KEPT_SLICES, N_THETA_D, N_THETA_H, NETWORK_INPUT_SHAPE

__all__ = ["GUARD_THETA_H_BINS", "GUARD_TOLERANCE", "guard_highlight", "guard_valid_mask"]

#: W: the guard's window, θh bins 0 … W − 1 of the MERL grid (θh below 60.8°). It covers the specular peak and
#: the body that issue 50's judge compares (θh < 2° against 40–60°, bins 0–13 and 60–73); unedited decodes of the
#: shipped model rise towards θh = 0 over it almost everywhere (the guard would change them by 1.4e-4 mapped on
#: average, ``reports/plausibility/highlight-guard.md``), while a window to 90 would flatten their grazing rise.
GUARD_THETA_H_BINS = 74
#: τ: how far (mapped units) an entry may fall below the largest entry further out in its column's window; 0.05 is
#: a factor 101^0.05 ≈ 1.26 on ρ/ε + 1.
GUARD_TOLERANCE = 0.05


@functools.cache
def guard_valid_mask(window: int = GUARD_THETA_H_BINS) -> npt.NDArray[np.bool_]:
    """(21 kept slots, ``window`` θh bins, 90 θd bins): the window's entries that lie above the horizon."""
    from brdfcodec.representation.mask import kept_slice_horizon_mask

    valid = np.ascontiguousarray(np.moveaxis(kept_slice_horizon_mask()[:window], -1, 0))
    valid.setflags(write=False)
    return valid


def guard_highlight(
    mapped: npt.ArrayLike, *, window: int = GUARD_THETA_H_BINS, tolerance: float = GUARD_TOLERANCE
) -> np.ndarray:
    """The guarded mapped slices of an edited record (the module docstring's g).

    Parameters
    ----------
    mapped : array_like, shape (..., 63, 90, 90)
        Clamped mapped slices in the network layout (colour-major channels, θh, θd), any float dtype.
    window : int, default :data:`GUARD_THETA_H_BINS`
        W, number of θh bins from 0 that the guard acts on, in [1, 90].
    tolerance : float, default :data:`GUARD_TOLERANCE`
        τ ≥ 0, mapped units.

    Returns
    -------
    ndarray, same shape and dtype as ``mapped``
        A new array; entries outside the window or below the horizon are copied unchanged. The guard reads
        past NaN values and leaves them NaN (a decoder clamps before it, so it sees none).

    Raises
    ------
    ValueError
        Wrong shape, a window outside [1, 90], or a negative or non-finite tolerance.
    """
    array = np.asarray(mapped)
    if array.shape[-3:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"expected mapped slices of shape (..., {NETWORK_INPUT_SHAPE}), got {array.shape}")
    if not 1 <= int(window) <= N_THETA_H:
        raise ValueError(f"window must be in [1, {N_THETA_H}], got {window}")
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"tolerance must be finite and ≥ 0, got {tolerance}")
    if not np.issubdtype(array.dtype, np.floating):
        array = array.astype(np.float32)
    out = array.copy()
    blocks = out.reshape(*out.shape[:-3], N_CHANNELS, N_KEPT_SLICES, N_THETA_H, N_THETA_D)
    valid = guard_valid_mask(int(window))
    part = blocks[..., :window, :]
    lowest = np.array(-np.inf, dtype=array.dtype)
    readable = np.where(valid, part, lowest)
    outer = np.fmax.accumulate(readable[..., ::-1, :], axis=-2)[..., ::-1, :]  # max over k ≥ i (NaN skipped)
    beyond = np.concatenate([outer[..., 1:, :], np.broadcast_to(lowest, (*outer.shape[:-2], 1, N_THETA_D))],
                            axis=-2)  # max over k > i
    floor = beyond - np.array(tolerance, dtype=array.dtype)
    blocks[..., :window, :] = np.where(valid & (floor > part), floor, part)  # NaN entries stay NaN
    return out
