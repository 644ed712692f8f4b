"""Stored MERL values ↔ reflectance (1/sr): the colour scale, applied in one place.

A MERL file stores, per colour channel c, a number whose reflectance in 1/sr
(linear RGB) is ``stored · S_c`` with ``S = (1, 1.15, 1.66) / 1500``
(:data:`~brdfcodec.conventions.MERL_COLOR_SCALE`, ``spec/conventions.md`` §3).

>>> import numpy as np
>>> stored = np.full((3, 2), 1500.0)
>>> reflectance_from_stored(stored)[:, 0]
array([1.  , 1.15, 1.66])
>>> stored_from_reflectance(reflectance_from_stored(stored))[:, 0]
array([1500., 1500., 1500.])
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import MERL_COLOR_SCALE, N_CHANNELS

__all__ = ["channel_scale", "reflectance_from_stored", "stored_from_reflectance"]


def channel_scale(ndim: int, *, channel_axis: int = 0, dtype: npt.DTypeLike = np.float64) -> np.ndarray:
    """The colour scale shaped to broadcast against an array of ``ndim`` axes.

    Parameters
    ----------
    ndim : int
        Number of axes of the array it multiplies.
    channel_axis : int, default 0
        Axis that holds R, G, B.
    dtype : dtype, default float64

    Returns
    -------
    ndarray
        Shape 1 on every axis but ``channel_axis`` (3); 1/sr per stored unit.
    """
    shape = [1] * ndim
    shape[channel_axis] = N_CHANNELS
    return MERL_COLOR_SCALE.astype(dtype).reshape(shape)


def _check_channels(array: np.ndarray, channel_axis: int) -> None:
    if array.ndim == 0 or array.shape[channel_axis] != N_CHANNELS:
        raise ValueError(f"axis {channel_axis} must hold {N_CHANNELS} channels, got shape {array.shape}")


def reflectance_from_stored(stored: npt.ArrayLike, *, channel_axis: int = 0) -> np.ndarray:
    """Reflectance (1/sr, linear RGB) of stored MERL values.

    Parameters
    ----------
    stored : array_like
        Stored MERL values; axis ``channel_axis`` has length 3.
    channel_axis : int, default 0

    Returns
    -------
    ndarray
        ``stored · S_c``; float32 input stays float32, anything else is float64.
        Negative (unmeasured) values stay negative: mask them as needed.
    """
    array = np.asarray(stored)
    _check_channels(array, channel_axis)
    dtype = np.float32 if array.dtype == np.float32 else np.float64
    return array * channel_scale(array.ndim, channel_axis=channel_axis, dtype=dtype)


def stored_from_reflectance(reflectance: npt.ArrayLike, *, channel_axis: int = 0) -> np.ndarray:
    """Stored MERL values of reflectance (1/sr): the inverse of :func:`reflectance_from_stored`.

    Parameters
    ----------
    reflectance : array_like
        Linear RGB reflectance in 1/sr; axis ``channel_axis`` has length 3.
    channel_axis : int, default 0

    Returns
    -------
    ndarray
        ``reflectance / S_c``; float32 input stays float32, anything else is float64.
    """
    array = np.asarray(reflectance)
    _check_channels(array, channel_axis)
    dtype = np.float32 if array.dtype == np.float32 else np.float64
    return array / channel_scale(array.ndim, channel_axis=channel_axis, dtype=dtype)
