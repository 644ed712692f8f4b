"""The log mapping of ``spec/conventions.md`` §4 and its inverse, on stored MERL values.

Per channel c, with ε = 0.01 and the colour scale S_c,

.. math::

    \\hat\\rho = \\frac{\\operatorname{log1p}(\\rho S_c / \\varepsilon)}{\\operatorname{log1p}(1/\\varepsilon)}

so 0 maps to 0 and a reflectance of 1/sr maps to 1.

>>> import numpy as np
>>> stored = np.array([[0.0, 1500.0], [0.0, 1500 / 1.15], [0.0, 1500 / 1.66]])
>>> np.round(map_values(stored), 12)
array([[0., 1.],
       [0., 1.],
       [0., 1.]])
>>> np.allclose(unmap_values(map_values(stored)), stored)
True
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import EPSILON, MAPPED_MAX, N_CHANNELS
from brdfcodec.representation.units import channel_scale

__all__ = ["LOG_RANGE", "clamp_mapped", "map_values", "unmap_values"]

FloatArray = npt.NDArray[np.floating]

#: Denominator of the mapping, log(1 + ε) − log(ε).
LOG_RANGE: Final = float(np.log1p(1.0 / EPSILON))


def _working_dtype(array: np.ndarray) -> np.dtype:
    """float64 stays float64; everything else is computed in float32."""
    return np.dtype(np.float64) if array.dtype == np.float64 else np.dtype(np.float32)


def _check_channels(array: np.ndarray, channel_axis: int) -> None:
    if array.ndim == 0 or array.shape[channel_axis] != N_CHANNELS:
        raise ValueError(f"axis {channel_axis} must hold {N_CHANNELS} channels, got shape {array.shape}")


def clamp_mapped(mapped: npt.ArrayLike, *, out: np.ndarray | None = None) -> FloatArray:
    """Limit mapped values to the mapped domain ``[0, MAPPED_MAX]``, NaN to 0.

    This is the one place where decoder output is clamped (``spec/conventions.md``
    §7: clamp, then interpolate, then unmap); every decoded value is then
    finite and non-negative.

    Parameters
    ----------
    mapped : array_like
        Mapped values of any shape (float32 or float64).
    out : ndarray, optional
        Where to write the result (may be ``mapped`` itself for in-place use).

    Returns
    -------
    ndarray
        Same shape; float64 stays float64, anything else becomes float32.

    Examples
    --------
    >>> clamp_mapped(np.array([-1.0, np.nan, 2.0, 9.0]))
    array([0., 0., 2., 5.])
    """
    array = np.asarray(mapped)
    dtype = _working_dtype(array)
    array = array.astype(dtype, copy=False)
    # Bounds of the array's own type keep numpy's vectorised clip (Python floats take it off that path, far slower).
    clipped = np.clip(array, dtype.type(0.0), dtype.type(MAPPED_MAX), out=out)
    # The clip keeps NaN and puts everything else in [0, MAPPED_MAX], so the sum is NaN exactly when a NaN is left.
    if np.isnan(np.sum(clipped)):
        clipped = np.nan_to_num(clipped, copy=not isinstance(clipped, np.ndarray), nan=0.0)  # 0-d: a scalar
    return clipped


def map_values(values: npt.ArrayLike, *, channel_axis: int = 0) -> FloatArray:
    """Log-map stored MERL values (paper, eq. 1).

    Parameters
    ----------
    values : array_like
        Stored MERL values, ≥ 0 for valid entries; negative (unmeasured)
        entries map to 0 and should be masked by the caller. The axis
        ``channel_axis`` has length 3 (R, G, B).
    channel_axis : int, default 0
        Axis holding the colour channels.

    Returns
    -------
    ndarray
        Mapped values, ≥ 0 (a reflectance of 1/sr maps to 1; the stored
        value 1e6 maps to at most 2.52). float64 input gives float64;
        float16 and float32 input give float32. Finite for finite input.
    """
    array = np.asarray(values)
    _check_channels(array, channel_axis)
    dtype = _working_dtype(array)
    scale = channel_scale(array.ndim, channel_axis=channel_axis, dtype=dtype) / dtype.type(EPSILON)
    positive = np.maximum(array.astype(dtype, copy=False), dtype.type(0))
    return np.log1p(positive * scale) / dtype.type(LOG_RANGE)


def unmap_values(mapped: npt.ArrayLike, *, channel_axis: int = 0) -> FloatArray:
    """Exact inverse of :func:`map_values`, clamped to the mapped domain.

    Parameters
    ----------
    mapped : array_like
        Mapped values; clamped to ``[0, MAPPED_MAX]`` first (:func:`clamp_mapped`),
        so any decoder output gives a finite, non-negative table.
    channel_axis : int, default 0
        Axis holding the colour channels.

    Returns
    -------
    ndarray
        Stored MERL values, in [0, about 1.6e11]. float64 input gives
        float64; float16 and float32 input give float32.
    """
    array = np.asarray(mapped)
    _check_channels(array, channel_axis)
    dtype = _working_dtype(array)
    clamped = clamp_mapped(array)
    scale = dtype.type(EPSILON) / channel_scale(array.ndim, channel_axis=channel_axis, dtype=dtype)
    return np.expm1(clamped * dtype.type(LOG_RANGE)) * scale
