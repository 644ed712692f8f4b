"""Tables to network inputs and network outputs back to tables: the two ends of the β-VAE.

Encoding side: a stored table (3, 90, 90, 180) becomes the network input
(63, 90, 90), its 21 kept φd slices log-mapped with invalid entries 0, and
the mask of valid entries (:func:`network_input_from_table`).

Decoding side (``spec/conventions.md`` §7): the decoder's mapped slices are
clamped to the mapped domain (:func:`~brdfcodec.representation.mapping.clamp_mapped`,
once), interpolated in the mapped domain to the φd bins asked for, and
unmapped to stored units (:func:`table_from_mapped`).

>>> import numpy as np
>>> from brdfcodec.conventions import NETWORK_INPUT_SHAPE
>>> ones = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)   # reflectance 1/sr everywhere
>>> table = table_from_network_output(ones, phi_d_bins=[0, 4])
>>> table.shape, table.dtype
((3, 90, 90, 2), dtype('float32'))
>>> np.round(table[:, 0, 0, 0] * [1.0, 1.15, 1.66] / 1500, 5)   # back to 1/sr
array([1., 1., 1.])
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import EPSILON, MERL_COLOR_SCALE, N_CHANNELS, N_KEPT_SLICES, NETWORK_INPUT_SHAPE
from brdfcodec.representation.layout import (
    from_network_layout,
    interpolation_plan,
    select_kept_slices,
    to_network_layout,
    validate_phi_d_bins,
)
from brdfcodec.representation.mapping import LOG_RANGE, clamp_mapped, map_values
from brdfcodec.representation.mask import validity_mask

__all__ = ["network_input_from_table", "reflectance_from_mapped", "table_from_mapped", "table_from_network_output"]


def network_input_from_table(
    values: npt.ArrayLike, mask: npt.ArrayLike | None = None
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
    """Network input and its mask for one table.

    Parameters
    ----------
    values : array_like, shape (3, 90, 90, 180)
        Stored MERL values.
    mask : array_like of bool, shape (3, 90, 90, 180), optional
        Valid entries; :func:`~brdfcodec.representation.mask.validity_mask` of ``values`` by default.

    Returns
    -------
    inputs : ndarray of float32, shape (63, 90, 90)
        Log-mapped kept slices in the network layout; invalid entries are 0.
    mask : ndarray of bool, shape (63, 90, 90)
        Valid entries, same layout.
    """
    table = np.asarray(values)
    valid = validity_mask(table) if mask is None else np.asarray(mask, dtype=bool)
    kept_mask = select_kept_slices(valid)
    kept_values = np.where(kept_mask, select_kept_slices(table), 0.0)
    mapped = np.where(kept_mask, map_values(kept_values), 0.0).astype(np.float32)
    return to_network_layout(mapped), to_network_layout(kept_mask)


@functools.cache
def _unmapping_matrix(phi_d_bins: tuple[int, ...]) -> np.ndarray:
    """(21, K) float32 matrix: interpolation weights to the chosen bins, times the mapping's log range."""
    left, right, weight = interpolation_plan()
    bins = np.asarray(phi_d_bins)
    matrix = np.zeros((N_KEPT_SLICES, len(bins)), dtype=np.float64)
    columns = np.arange(len(bins))
    matrix[left[bins], columns] += 1.0 - weight[bins]
    matrix[right[bins], columns] += weight[bins]
    out = (matrix * LOG_RANGE).astype(np.float32)
    out.setflags(write=False)
    return out


_STORED_PER_EXPM1 = (EPSILON / MERL_COLOR_SCALE).astype(np.float32).reshape(N_CHANNELS, 1, 1, 1)


def _interpolated_expm1(mapped: npt.ArrayLike, phi_d_bins: Sequence[int] | None) -> np.ndarray:
    """expm1 of the mapped slices interpolated to the chosen bins times the log range: reflectance · S_c / ε."""
    bins = validate_phi_d_bins(phi_d_bins)
    array = np.asarray(mapped, dtype=np.float32)
    if array.shape[-3:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"mapped must have shape (..., {', '.join(map(str, NETWORK_INPUT_SHAPE))}), got {array.shape}")
    kept = from_network_layout(array)  # (..., 3, 90, 90, 21)
    table = np.matmul(kept, _unmapping_matrix(bins))
    return np.expm1(table, out=table)


def reflectance_from_mapped(
    mapped: npt.ArrayLike, *, phi_d_bins: Sequence[int] | None = None
) -> npt.NDArray[np.float32]:
    """Reflectance (1/sr) from mapped slices in the mapped domain: :func:`table_from_mapped` without the colour scale.

    The mapping is the same function of reflectance in every channel, so
    reflectance is ``ε · expm1(·)`` directly; going through stored units would
    divide by the colour scale and multiply it back.

    Returns
    -------
    ndarray of float32, shape (..., 3, 90, 90, K)
        Finite and ≥ 0; equal to ``reflectance_from_stored(table_from_mapped(mapped))``
        up to float32 rounding.
    """
    table = _interpolated_expm1(mapped, phi_d_bins)
    table *= np.float32(EPSILON)
    return table


def table_from_mapped(mapped: npt.ArrayLike, *, phi_d_bins: Sequence[int] | None = None) -> npt.NDArray[np.float32]:
    """Table (or chosen φd bins) in stored units from mapped slices already in the mapped domain.

    Parameters
    ----------
    mapped : array_like, shape (..., 63, 90, 90)
        Mapped values in ``[0, MAPPED_MAX]`` in the network layout (clamped
        decoder output: :meth:`brdfcodec.codec.BrdfDecoder.decode_mapped`).
        Values outside the domain are not checked; use
        :func:`table_from_network_output` for raw network output.
    phi_d_bins : sequence of int, optional
        φd bins to produce, each in [0, 180); all 180 by default. One bin
        costs 1/180 of the full table.

    Returns
    -------
    ndarray of float32, shape (..., 3, 90, 90, K)
        Stored MERL values, finite and ≥ 0: the slices are interpolated in the
        mapped domain (``spec/conventions.md`` §7), then unmapped (§4). Both
        steps are one product with a (21, K) weight matrix followed by
        ``expm1`` and the channel scale; a kept bin has weight exactly 1, so
        it equals :func:`~brdfcodec.representation.mapping.unmap_values` of
        the decoder's slice up to float32 rounding of the log range.
    """
    table = _interpolated_expm1(mapped, phi_d_bins)
    table *= _STORED_PER_EXPM1
    return table


def table_from_network_output(
    output: npt.ArrayLike, *, phi_d_bins: Sequence[int] | None = None
) -> npt.NDArray[np.float32]:
    """Table in stored units from raw network output (any values): clamp once, then :func:`table_from_mapped`.

    Parameters
    ----------
    output : array_like, shape (..., 63, 90, 90)
        Mapped values in the network layout; clamped to ``[0, MAPPED_MAX]``
        first (NaN becomes 0).
    phi_d_bins : sequence of int, optional
        As for :func:`table_from_mapped`.

    Returns
    -------
    ndarray of float32, shape (..., 3, 90, 90, K)
    """
    return table_from_mapped(clamp_mapped(np.asarray(output, dtype=np.float32)), phi_d_bins=phi_d_bins)
