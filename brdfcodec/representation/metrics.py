"""Error metrics between a reference table and a reconstruction (``spec/conventions.md`` §8).

All metrics take full tables in MERL layout ``(3, 90, 90, 180)`` and MERL
stored units, and use only the entries valid in the reference (its mask, or
:func:`brdfcodec.representation.mask.validity_mask` of the reference by default).

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

A RelAE is a ratio to the reference's magnitude, so it means nothing for a
near-black reference: where every compared entry's physical reflectance is
below :data:`NEAR_BLACK_REFLECTANCE` (1e-6 /sr; all zeros, denormals,
1e-30 …), the RelAE (overall, or of that channel) is NaN, undefined, and
:func:`mean_absolute_error` is the error to report instead.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import TABLE_SHAPE
from brdfcodec.representation import map_values, reflectance_from_stored
from brdfcodec.representation.coords import grid_direction_cosines
from brdfcodec.representation.mask import validity_mask

__all__ = [
    "NEAR_BLACK_REFLECTANCE",
    "ChannelErrors",
    "ErrorReport",
    "RelaeAgainst",
    "relae_between_mapped",
    "relae_both",
    "cosine_weighted_rmse",
    "error_report",
    "mean_absolute_error",
    "near_black",
    "relae_linear",
    "relae_mapped",
]

#: Largest physical reflectance (1/sr) of a near-black reference: below it on every compared entry, RelAE is
#: undefined (NaN) and an absolute error is reported instead (``spec/conventions.md`` §8).
NEAR_BLACK_REFLECTANCE: Final = 1e-6


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
    if (valid & ~np.isfinite(est)).any():
        raise ValueError("estimate holds NaN or infinite values at valid entries")
    return ref, est, valid


#: θh rows per block of a blockwise sum: a (3, 10, 90, 180) float64 block is 3.9 MB, so a metric's temporaries
#: stay in cache and are reused instead of being allocated (and page-faulted) as whole 35 MB tables.
_BLOCK_ROWS: Final = 10
_BLOCKS: Final = tuple(np.s_[:, i : i + _BLOCK_ROWS] for i in range(0, TABLE_SHAPE[1], _BLOCK_ROWS))
Transform = Callable[[np.ndarray], np.ndarray]


def _identity(values: np.ndarray) -> np.ndarray:
    return values


def _masked_abs_sums(values: np.ndarray, invalid: np.ndarray, *, owned: bool = False) -> np.ndarray:
    """Per-channel sums of ``|values|`` over valid entries, shape (3,); ``owned``: ``values`` may be overwritten."""
    magnitude = np.abs(values, out=values) if owned else np.abs(values)
    np.copyto(magnitude, 0.0, where=invalid)
    return magnitude.reshape(3, -1).sum(axis=1)


def _error_sums(transform: Transform, reference: np.ndarray, estimate: np.ndarray, invalid: np.ndarray,
                *, reference_done: bool = False) -> np.ndarray:
    """Per-channel ``Σ |T(est) − T(ref)|`` over valid entries, block by block (``reference_done``: ref is T(ref))."""
    sums = np.zeros(3)
    for block in _BLOCKS:
        ref = reference[block] if reference_done else transform(reference[block])
        sums += _masked_abs_sums(np.subtract(transform(estimate[block]), ref), invalid[block], owned=True)
    return sums


def _magnitude_sums(transform: Transform, reference: np.ndarray, invalid: np.ndarray) -> np.ndarray:
    """Per-channel ``Σ |T(ref)|`` over valid entries, block by block."""
    sums = np.zeros(3)
    for block in _BLOCKS:
        sums += _masked_abs_sums(transform(reference[block]), invalid[block], owned=True)
    return sums


def _channel_errors(error_sums: np.ndarray, magnitude_sums: np.ndarray,
                    defined: np.ndarray | None = None) -> ChannelErrors:
    """Ratios per channel and overall; NaN where the magnitude is 0 or (``defined``, per channel) near black."""
    usable = magnitude_sums > 0 if defined is None else (magnitude_sums > 0) & defined
    with np.errstate(all="ignore"):  # a denormal magnitude would overflow the ratio: such channels are near black
        per_channel = np.divide(error_sums, magnitude_sums, out=np.full(3, np.nan), where=usable)
        total = magnitude_sums.sum()  # every channel's error counts once one channel makes the ratio meaningful
        overall = float(error_sums.sum() / total) if usable.any() and total > 0 else float("nan")
    if not np.isfinite(overall):
        overall = float("nan")
    per_channel[~np.isfinite(per_channel)] = np.nan
    return ChannelErrors(overall, *(float(v) for v in per_channel))


def _defined_channels(ref: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per channel: is the reference's largest compared physical reflectance at least NEAR_BLACK_REFLECTANCE?"""
    peak = np.where(valid, np.abs(ref), 0.0).reshape(3, -1).max(axis=1)
    return np.asarray(reflectance_from_stored(peak[:, None, None, None])).reshape(3) >= NEAR_BLACK_REFLECTANCE


def near_black(reference: npt.ArrayLike, mask: npt.ArrayLike | None = None) -> bool:
    """Whether a table is near black: every valid entry's physical reflectance below :data:`NEAR_BLACK_REFLECTANCE`.

    Parameters
    ----------
    reference : array_like, shape (3, 90, 90, 180)
        Stored MERL values.
    mask : array_like of bool, shape (3, 90, 90, 180), optional
        Entries to look at; the reference's validity mask by default.

    Returns
    -------
    bool
        True for all zeros, denormals or 1e-30; its RelAE is then undefined (NaN).
    """
    ref, _, valid = _prepare(reference, reference, mask)
    return not _defined_channels(ref, valid).any()


def mean_absolute_error(
    reference: npt.ArrayLike, estimate: npt.ArrayLike, mask: npt.ArrayLike | None = None
) -> ChannelErrors:
    """Mean absolute difference of physical reflectance over the valid entries (the error of a near-black source).

    Parameters and arrays as :func:`relae_linear`.

    Returns
    -------
    ChannelErrors
        In 1/sr, ≥ 0 and finite; NaN only for a channel without a valid entry.
    """
    ref, est, valid = _prepare(reference, estimate, mask)
    sums = _error_sums(reflectance_from_stored, ref, est, ~valid)
    counts = valid.reshape(3, -1).sum(axis=1)
    per_channel = np.divide(sums, counts, out=np.full(3, np.nan), where=counts > 0)
    overall = float(sums.sum() / counts.sum()) if counts.sum() else float("nan")
    return ChannelErrors(overall, *(float(v) for v in per_channel))


def _relative_absolute(ref: np.ndarray, est: np.ndarray, valid: np.ndarray,
                       transform: Transform = _identity) -> ChannelErrors:
    """RelAE of ``transform``-ed values (the identity for tables already mapped: no near-black rule there)."""
    invalid = ~valid
    defined = None if transform is _identity else _defined_channels(ref, valid)
    return _channel_errors(_error_sums(transform, ref, est, invalid), _magnitude_sums(transform, ref, invalid),
                           defined)


class RelaeAgainst:
    """RelAE of many estimates against one reference: the reference is checked, transformed and summed once.

    What rate control uses to measure each candidate of an error target; the
    numbers are those of :func:`relae_mapped` or :func:`relae_linear`.

    Parameters
    ----------
    reference : array_like, shape (3, 90, 90, 180)
        Stored MERL values.
    mask : array_like of bool, shape (3, 90, 90, 180), optional
        Entries to compare; the reference's validity mask by default.
    metric : {"mapped", "linear"}

    Examples
    --------
    >>> import numpy as np
    >>> reference = np.full((3, 90, 90, 180), 0.5)
    >>> against = RelaeAgainst(reference, metric="linear")
    >>> round(against(0.75 * reference).overall, 12)
    0.25
    """

    def __init__(self, reference: npt.ArrayLike, mask: npt.ArrayLike | None = None,
                 metric: str = "mapped") -> None:
        if metric not in ("mapped", "linear"):
            raise ValueError(f"metric must be 'mapped' or 'linear', got {metric!r}")
        ref, _, valid = _prepare(reference, reference, mask)
        self._transform = map_values if metric == "mapped" else reflectance_from_stored
        self._valid, self._invalid = valid, ~valid
        self._defined = _defined_channels(ref, valid)
        self._reference = self._transform(ref)
        self._magnitude_sums = _magnitude_sums(_identity, self._reference, self._invalid)

    def __call__(self, estimate: npt.ArrayLike) -> ChannelErrors:
        """RelAE of ``estimate`` (stored units, shape (3, 90, 90, 180)) against the reference."""
        est = np.asarray(estimate, dtype=np.float64)
        if est.shape != TABLE_SHAPE:
            raise ValueError(f"estimate must have shape {TABLE_SHAPE}, got {est.shape}")
        if (self._valid & ~np.isfinite(est)).any():
            raise ValueError("estimate holds NaN or infinite values at valid entries")
        error_sums = _error_sums(self._transform, self._reference, est, self._invalid, reference_done=True)
        return _channel_errors(error_sums, self._magnitude_sums, self._defined)

    @property
    def defined(self) -> bool:
        """False for a near-black reference (:func:`near_black`): every RelAE against it is NaN."""
        return bool(self._defined.any())


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
        reference is near black (every compared entry below
        :data:`NEAR_BLACK_REFLECTANCE` /sr: zero, denormal, 1e-30 …).
    """
    return _relae_linear(*_prepare(reference, estimate, mask))


def relae_mapped(
    reference: npt.ArrayLike, estimate: npt.ArrayLike, mask: npt.ArrayLike | None = None
) -> ChannelErrors:
    """RelAE of log-mapped values (the paper's variant).

    Parameters and return as :func:`relae_linear`.
    """
    return _relae_mapped(*_prepare(reference, estimate, mask))


def relae_both(
    reference: npt.ArrayLike, estimate: npt.ArrayLike, mask: npt.ArrayLike | None = None
) -> tuple[ChannelErrors, ChannelErrors]:
    """:func:`relae_linear` and :func:`relae_mapped` at once (the arrays checked once; what ``measure`` records).

    Parameters as :func:`relae_linear`.

    Returns
    -------
    linear, mapped : ChannelErrors
    """
    prepared = _prepare(reference, estimate, mask)
    return _relae_linear(*prepared), _relae_mapped(*prepared)


def _relae_linear(ref: np.ndarray, est: np.ndarray, valid: np.ndarray) -> ChannelErrors:
    return _relative_absolute(ref, est, valid, reflectance_from_stored)


def _relae_mapped(ref: np.ndarray, est: np.ndarray, valid: np.ndarray) -> ChannelErrors:
    return _relative_absolute(ref, est, valid, map_values)


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
    return _cosine_weighted_rmse(*_prepare(reference, estimate, mask))


def _cosine_weighted_rmse(ref: np.ndarray, est: np.ndarray, valid: np.ndarray) -> ChannelErrors:
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
    prepared = _prepare(reference, estimate, mask)
    return ErrorReport(
        relae_linear=_relae_linear(*prepared),
        relae_mapped=_relae_mapped(*prepared),
        cosine_weighted_rmse=_cosine_weighted_rmse(*prepared),
    )
