"""Edge slots: kept φd slots that are not valid themselves but shape valid bins through the interpolation.

A decoded table is the linear interpolation of its 21 kept φd slices (``spec/bvae-format.md`` §6). Where a kept
slot of a (colour, θh, θd) cell lies below the horizon (or is unmeasured) and a valid bin lies between it and the
next kept slot, the value decoded at that slot enters the valid bin: ``(1 − t)·v_a + t·v_b``. The network input
(:func:`~brdfcodec.representation.network_io.network_input_from_table`) holds 0 there and its mask leaves the slot
out, so nothing fits it: on the grid's horizon band the interpolation runs towards an unfitted value, a floor of
error under every record's size (measured: ``reports/edge-slots/``, documentation: Results).

:func:`edge_slot_targets` gives each such slot the value that fits its valid bins best (least squares in mapped
units, the valid neighbour slot held at the source's value) and a weight: the share of a fully valid slot's
influence that the slot has on valid bins. Training uses them (``bvae train --edge-slots``), and so can the PCA
baselines of the rate–distortion runner; the decode is unchanged.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import KEPT_PHI_D_SLICES, MAPPED_MAX, N_KEPT_SLICES, TABLE_SHAPE
from brdfcodec.representation.layout import select_kept_slices, to_network_layout
from brdfcodec.representation.mapping import map_values

__all__ = ["edge_slot_targets"]

#: The summed interpolation weight of an interior kept slot over its two gaps (9 bins each way: 1 + 2·(8/9 + … +
#: 1/9) = 9): a fully valid slot weighs 1 in the reconstruction loss for this much.
_INTERIOR_WEIGHT = float(KEPT_PHI_D_SLICES[1] - KEPT_PHI_D_SLICES[0])


def edge_slot_targets(
    values: npt.ArrayLike, valid: npt.ArrayLike
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Targets and weights of the edge slots of one table, in the network layout.

    Parameters
    ----------
    values : array_like, shape (3, 90, 90, 180)
        Stored MERL values (any sign where not valid).
    valid : array_like of bool, shape (3, 90, 90, 180)
        Valid entries (:func:`~brdfcodec.representation.mask.validity_mask`).

    Returns
    -------
    targets : ndarray of float32, shape (63, 90, 90)
        At each edge slot (a kept slot that is not valid, next to a gap between kept slots with a valid bin whose
        other end is valid), the mapped value in ``[0, MAPPED_MAX]`` that minimises the squared mapped error of
        the valid bins of those gaps; 0 elsewhere.
    weights : ndarray of float32, shape (63, 90, 90)
        At each edge slot, the summed interpolation weight of the slot over those valid bins, over a fully valid
        interior slot's (9), in (0, 1]; 0 elsewhere (valid slots included: their weight is the input mask's).

    Raises
    ------
    ValueError
        The arrays are not of the table's shape.
    """
    table = np.asarray(values, dtype=np.float64)
    ok = np.asarray(valid, dtype=bool)
    if table.shape != TABLE_SHAPE or ok.shape != TABLE_SHAPE:
        raise ValueError(f"values and valid must have shape {TABLE_SHAPE}, got {table.shape} and {ok.shape}")
    kept_valid = select_kept_slices(ok)
    # only the (θh, θd) cells with valid and invalid kept slots can have an edge slot (the horizon's band)
    rows, columns = np.nonzero((kept_valid.any(axis=-1) & ~kept_valid.all(axis=-1)).any(axis=0))
    targets = np.zeros(kept_valid.shape, dtype=np.float32)
    weights = np.zeros(kept_valid.shape, dtype=np.float32)
    if len(rows):
        part_ok = ok[:, rows, columns]  # (3, cells, 180)
        part_targets, part_weights = _fitted(map_values(np.where(part_ok, table[:, rows, columns], 0.0)), part_ok)
        targets[:, rows, columns] = part_targets
        weights[:, rows, columns] = part_weights
    return to_network_layout(targets), to_network_layout(weights)


def _fitted(mapped: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`edge_slot_targets` on cells: mapped values and validity (..., 180) to targets and weights (..., 21)."""
    kept_valid = select_kept_slices(ok)
    kept_mapped = select_kept_slices(mapped)
    numerator = np.zeros(kept_valid.shape)
    denominator = np.zeros(kept_valid.shape)
    influence = np.zeros(kept_valid.shape)
    for gap in range(N_KEPT_SLICES - 1):
        left, right = KEPT_PHI_D_SLICES[gap], KEPT_PHI_D_SLICES[gap + 1]
        t = (np.arange(left + 1, right) - left) / (right - left)  # the right slot's weight inside the gap
        inside = ok[..., left + 1 : right]
        y = mapped[..., left + 1 : right]
        for slot, other, weight in ((gap + 1, gap, t), (gap, gap + 1, 1.0 - t)):
            # the slot is invalid and the gap's other end valid: fit the slot to the gap's valid bins
            use = (~kept_valid[..., slot] & kept_valid[..., other])[..., None] & inside
            if not use.any():
                continue
            neighbour = kept_mapped[..., other][..., None] * (1.0 - weight)
            numerator[..., slot] += np.where(use, weight * (y - neighbour), 0.0).sum(axis=-1)
            denominator[..., slot] += np.where(use, weight * weight, 0.0).sum(axis=-1)
            influence[..., slot] += np.where(use, weight, 0.0).sum(axis=-1)
    edge = denominator > 0.0
    targets = np.where(edge, np.clip(numerator / np.where(edge, denominator, 1.0), 0.0, MAPPED_MAX), 0.0)
    weights = np.where(edge, np.minimum(influence / _INTERIOR_WEIGHT, 1.0), 0.0)
    return targets.astype(np.float32), weights.astype(np.float32)
