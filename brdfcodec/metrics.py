"""Error metrics between a reference table and a reconstruction (``spec/conventions.md`` §8).

All metrics take full tables in MERL layout ``(3, 90, 90, 180)`` and MERL
stored units, and use only the entries valid in the reference (its mask, or
:func:`brdfcodec.mask.validity_mask` of the reference by default).

RelAE (relative absolute error), for a set E of valid entries::

    RelAE = Σ_E |ρ̃ − ρ| / Σ_E |ρ|

- ``relae_linear``: ρ is physical reflectance (stored × colour scale, 1/sr).
  Strict; dominated by the brightest (specular, grazing) entries.
- ``relae_mapped``: ρ is the log-mapped value of the paper's eq. 1. This is
  the variant of the size of the paper's figures (0.03 – 0.09).

Both are reported overall (E = valid entries of every channel) and per
channel (E = valid entries of that channel).

Cosine-weighted RMSE::

    RMSE_cos = sqrt( Σ_E (cos θi · (ρ̃ − ρ))² / |E| )

with ρ physical and θi the incoming direction's elevation at the entry's
representative angles.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import TABLE_SHAPE
from brdfcodec.coords import grid_direction_cosines
from brdfcodec.mask import validity_mask
from brdfcodec.representation import map_values, reflectance_from_stored

__all__ = [
    "ChannelErrors",
    "ErrorReport",
    "relae_between_mapped",
    "cosine_weighted_rmse",
    "error_report",
    "relae_linear",
    "relae_mapped",
]

@dataclass(frozen=True)
class ChannelErrors:
    """The values of one metric, overall and per channel (a result, not an exception).

    Attributes
    ----------
    overall : float
        Over the valid entries of all channels.
    red, green, blue : float
        Over the valid entries of one channel.
    """

    overall: float
    red: float
    green: float
    blue: float

    def as_dict(self) -> dict[str, float]:
        """The four numbers keyed ``overall``, ``red``, ``green``, ``blue``."""
        return {"overall": self.overall, "red": self.red, "green": self.green, "blue": self.blue}


@dataclass(frozen=True)
class ErrorReport:
    """All metrics of one reconstruction."""

    relae_linear: ChannelErrors
    relae_mapped: ChannelErrors
    cosine_weighted_rmse: ChannelErrors

    def as_dict(self) -> dict[str, dict[str, float]]:
        """Nested dictionary, metric name to :meth:`ChannelErrors.as_dict`."""
        return {
            "relae_linear": self.relae_linear.as_dict(),
            "relae_mapped": self.relae_mapped.as_dict(),
            "cosine_weighted_rmse": self.cosine_weighted_rmse.as_dict(),
        }


def _prepare(
    reference: npt.ArrayLike, estimate: npt.ArrayLike, mask: npt.ArrayLike | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ref = np.asarray(reference, dtype=np.float64)
    est = np.asarray(estimate, dtype=np.float64)
    for label, array in (("reference", ref), ("estimate", est)):
        if array.shape != TABLE_SHAPE:
            raise ValueError(f"{label} must have shape {TABLE_SHAPE}, got {array.shape}")
    valid = validity_mask(ref) if mask is None else np.asarray(mask, dtype=bool)
    if valid.shape != TABLE_SHAPE:
        raise ValueError(f"mask must have shape {TABLE_SHAPE}, got {valid.shape}")
    if not np.isfinite(est[valid]).all():
        raise ValueError("estimate holds NaN or infinite values at valid entries")
    return ref, est, valid


def _relative_absolute(ref: np.ndarray, est: np.ndarray, valid: np.ndarray) -> ChannelErrors:
    error = np.where(valid, np.abs(est - ref), 0.0).reshape(3, -1).sum(axis=1)
    magnitude = np.where(valid, np.abs(ref), 0.0).reshape(3, -1).sum(axis=1)
    per_channel = np.divide(error, magnitude, out=np.full(3, np.nan), where=magnitude > 0)
    total = magnitude.sum()
    overall = float(error.sum() / total) if total > 0 else float("nan")
    return ChannelErrors(overall, *(float(v) for v in per_channel))


def relae_linear(
    reference: npt.ArrayLike, estimate: npt.ArrayLike, mask: npt.ArrayLike | None = None
) -> ChannelErrors:
    """RelAE of physical reflectance (strict variant).

    Parameters
    ----------
    reference, estimate : array_like, shape (3, 90, 90, 180)
        Stored MERL values.
    mask : array_like of bool, shape (3, 90, 90, 180), optional
        Entries to compare; the reference's validity mask by default.

    Returns
    -------
    ChannelErrors
        Dimensionless, ≥ 0 (0 for a perfect reconstruction); NaN where the
        reference is zero on every compared entry.
    """
    ref, est, valid = _prepare(reference, estimate, mask)
    return _relative_absolute(reflectance_from_stored(ref), reflectance_from_stored(est), valid)


def relae_mapped(
    reference: npt.ArrayLike, estimate: npt.ArrayLike, mask: npt.ArrayLike | None = None
) -> ChannelErrors:
    """RelAE of log-mapped values (the paper's variant).

    Parameters and return as :func:`relae_linear`.
    """
    ref, est, valid = _prepare(reference, estimate, mask)
    return _relative_absolute(map_values(ref), map_values(est), valid)


def relae_between_mapped(
    mapped_reference: npt.ArrayLike, mapped_estimate: npt.ArrayLike, mask: npt.ArrayLike
) -> ChannelErrors:
    """The mapped RelAE of :func:`relae_mapped`, from tables already mapped (map a reference once, compare often).

    Parameters
    ----------
    mapped_reference, mapped_estimate : array_like, shape (3, 90, 90, 180)
        :func:`~brdfcodec.representation.map_values` of the reference and
        of the estimate (e.g. a decoder's mapped output interpolated to 180
        φd bins: the inverse mapping is exact on the mapped domain, so no
        round trip through stored units is needed).
    mask : array_like of bool, shape (3, 90, 90, 180)
        Entries to compare (the reference's valid entries).

    Returns
    -------
    ChannelErrors

    Examples
    --------
    >>> import numpy as np
    >>> reference = np.ones((3, 90, 90, 180))
    >>> relae_between_mapped(reference, 1.5 * reference, reference > 0).overall
    0.5
    """
    ref, est, valid = _prepare(mapped_reference, mapped_estimate, mask)
    return _relative_absolute(ref, est, valid)


@functools.cache
def _cos_theta_in() -> np.ndarray:
    cos = np.clip(grid_direction_cosines()[0], 0.0, 1.0)
    cos.setflags(write=False)
    return cos


def cosine_weighted_rmse(
    reference: npt.ArrayLike, estimate: npt.ArrayLike, mask: npt.ArrayLike | None = None
) -> ChannelErrors:
    """Root mean square of cos θi-weighted differences of physical reflectance.

    Parameters and return as :func:`relae_linear`; the unit is 1/sr.
    """
    ref, est, valid = _prepare(reference, estimate, mask)
    weighted = reflectance_from_stored(est - ref) * _cos_theta_in()[None]
    squared = np.where(valid, weighted**2, 0.0).reshape(3, -1)
    counts = valid.reshape(3, -1).sum(axis=1)
    per_channel = np.sqrt(np.divide(squared.sum(axis=1), counts, out=np.full(3, np.nan), where=counts > 0))
    overall = float(np.sqrt(squared.sum() / counts.sum())) if counts.sum() else float("nan")
    return ChannelErrors(overall, *(float(v) for v in per_channel))


def error_report(
    reference: npt.ArrayLike, estimate: npt.ArrayLike, mask: npt.ArrayLike | None = None
) -> ErrorReport:
    """All metrics at once (the reference mask is computed once)."""
    ref, est, valid = _prepare(reference, estimate, mask)
    return ErrorReport(
        relae_linear=relae_linear(ref, est, valid),
        relae_mapped=relae_mapped(ref, est, valid),
        cosine_weighted_rmse=cosine_weighted_rmse(ref, est, valid),
    )
