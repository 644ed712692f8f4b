"""A training penalty that keeps latent traversals plausible (issue 12, item 5).

The shipped model's traversals invert specular peaks, dig black holes into
highlights and inflate energy (``brdfcodec.edit.plausibility``; model card,
"Plausibility of traversals"), mostly through its linear path. This penalty
decodes a traversed code ``z' = μ + t·e_d`` (d uniform over the latent
dimensions, t uniform in ``[−range, range]`` prior σ) for every material of
a batch and adds hinge terms on the decoder's *unbounded* output ``u'``
(before the clamp to the mapped domain), each a sum over cells or entries so
that it weighs like the reconstruction, which is a sum over valid entries:

``inversion``
    Σ over cells (colour, kept φd slot, θd bin; all five θh entries above the
    horizon) of ``relu(D(max(u', 0)) − max(D(x), 0) − margin)``, where ``D`` is the
    specular deficit ``max(m[θh 4–6]) − max(m[θh 0–1])`` of
    :func:`brdfcodec.edit.plausibility.specular_deficit` and ``x`` the material the
    batch shows (after augmentation): a traversal may not open a deficit that
    the material lacks.
``holes``
    Σ over near-specular entries (θh bins 0–1, above the horizon) where the
    material is above 0 and the decode's flank (θh bins 4–6) is lit, of
    ``relu(min(x, hole_margin) − u')``: the peak may not cross the floor of the
    mapped domain under a lit flank, where the clamp would make it a black hole
    (a region that goes black as a whole is not penalised). With
    ``hole_margin`` > 0 it must stay that far above the floor (or at the
    material's own value, where that is lower), so that the hinge still pushes
    where the output hovers just above 0: the plausibility check counts a
    single clamped entry as a hole.
``pits`` (only with ``pit_weight`` > 0)
    ``pit_weight`` · Σ over the window of the *pits* check (θh bins i < 20,
    above the horizon; :mod:`brdfcodec.representation.highlight`) of
    ``relu(R_i − max(u'_i, 0) − P − margin)``, ``R_i`` the largest floored
    output at bins i + 1 to 20 of the same cell (held fixed: the centre is
    lifted, the ring is not lowered) and ``P`` the material's own largest
    such fall in that cell: a traversal may not darken a highlight towards
    its centre more than the material does.
``energy``
    ``ENERGY_SCALE`` · Σ over colours of ``relu(log A_c(u') − log A_max)``:
    the white-sky albedo (:func:`brdfcodec.edit.plausibility.white_sky_albedo`, of
    the output clamped to ``[0, ENERGY_CEILING]``, twice the mapped domain, so
    that saturated peaks keep a gradient) may not exceed ``A_max``, the
    largest channel albedo of the training materials times
    ``1 + energy_margin``.

μ is detached: the penalty shapes the decoder, not where the encoder puts
materials. The draws (d, t) are made by the trainer from the run's generator,
so runs stay reproducible.

Examples
--------
>>> import torch
>>> x = torch.full((1, 63, 90, 90), 0.5)
>>> penalty = TraversalPenalty(x)
>>> terms = penalty(x.clone(), x)
>>> [round(float(v), 6) for v in (terms.inversion[0], terms.holes[0], terms.energy[0])]
[0.0, 0.0, 0.0]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from brdfcodec.conventions import EPSILON, MAPPED_MAX, N_CHANNELS, N_KEPT_SLICES, N_THETA_D, N_THETA_H
from brdfcodec.edit.plausibility import (
    NEAR_THETA_H_BINS,
    OFF_THETA_H_BINS,
    albedo_weights,
    cell_valid_mask,
    entry_valid_mask,
)
from brdfcodec.representation.highlight import PIT_THETA_H_BINS, window_valid_mask
from brdfcodec.representation.mapping import LOG_RANGE

__all__ = ["ENERGY_CEILING", "ENERGY_SCALE", "TraversalPenalty", "TraversalTerms", "traversed_codes"]

#: Weight of one unit of log-albedo excess per colour, against the other terms' sums over cells.
ENERGY_SCALE = 100.0
#: Mapped ceiling of the energy term's albedo: twice the decode's, so saturated peaks keep a gradient
#: (ρ/ε ≤ 101¹⁰, finite in float32).
ENERGY_CEILING = 2 * MAPPED_MAX
_NEAR = list(NEAR_THETA_H_BINS)
_OFF = list(OFF_THETA_H_BINS)


@dataclass(frozen=True)
class TraversalTerms:
    """The penalty's parts per sample, each shape (B,) and ≥ 0."""

    inversion: torch.Tensor
    holes: torch.Tensor
    energy: torch.Tensor
    pits: torch.Tensor

    def total(self) -> torch.Tensor:
        """Sum of the parts, shape (B,)."""
        return self.inversion + self.holes + self.energy + self.pits


def _blocks(mapped: torch.Tensor) -> torch.Tensor:
    """(B, 63, 90, 90) network layout as (B, 3, 21, θh 90, θd 90)."""
    return mapped.reshape(mapped.shape[0], N_CHANNELS, N_KEPT_SLICES, N_THETA_H, N_THETA_D)


def _deficit(blocks: torch.Tensor) -> torch.Tensor:
    """max(m[θh 4–6]) − max(m[θh 0–1]) per (B, colour, slot, θd)."""
    return blocks[..., _OFF, :].amax(dim=-2) - blocks[..., _NEAR, :].amax(dim=-2)


def _falls(blocks: torch.Tensor, window: torch.Tensor) -> torch.Tensor:
    """R_i − m_i per (B, colour, slot, θh bin i < 20, θd) where bin i and some bin beyond it lie above the horizon
    (0 elsewhere): R_i the largest value at bins i + 1 to 20, held fixed (detached)."""
    inside = blocks[..., :PIT_THETA_H_BINS, :]
    floor = torch.finfo(inside.dtype).min
    masked = inside.detach().masked_fill(~window, floor)
    outer = torch.flip(torch.cummax(torch.flip(masked, dims=[-2]), dim=-2).values, dims=[-2])[..., 1:, :]
    usable = window[:, :-1, :] & (outer > floor)
    return torch.where(usable, outer - inside[..., :-1, :], torch.zeros_like(outer))


def _albedo(mapped_blocks: torch.Tensor, weights: torch.Tensor, ceiling: float = MAPPED_MAX) -> torch.Tensor:
    """White-sky albedo per (B, colour) of mapped blocks, clamped to ``[0, ceiling]`` first."""
    reflectance = torch.expm1(mapped_blocks.clamp(0.0, ceiling) * LOG_RANGE) * EPSILON
    return torch.einsum("bcshd,shd->bc", reflectance, weights)


def traversed_codes(mu: torch.Tensor, dims: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """``μ + t·e_d`` per row: ``mu`` (B, M) detached, ``dims`` (B,) in [0, M) or unit directions (B, M),
    ``offsets`` (B,) prior σ units."""
    direction = (dims.to(mu.dtype) if dims.ndim == 2
                 else torch.nn.functional.one_hot(dims.long(), mu.shape[1]).to(mu.dtype))
    step = direction * offsets.to(mu.dtype)[:, None]
    return mu.detach() + step.to(mu.device)


class TraversalPenalty:
    """Hinge penalties on a traversed decode (see the module docstring).

    Parameters
    ----------
    train_inputs : Tensor, shape (N, 63, 90, 90)
        Mapped training materials; their largest channel albedo sets ``A_max``.
    margin : float, default 0.05
        Deficit allowed beyond the material's own, mapped units (the
        plausibility check flags deficits above 0.1).
    energy_margin : float, default 0.1
        Relative margin of ``A_max`` over the training materials' largest albedo
        (the plausibility check's ``energetic`` margin).
    hole_margin : float, default 0
        Mapped height above the floor that a lit highlight's near-specular entries must keep (``holes``);
        0 penalises only crossing the floor.
    pit_weight : float, default 0
        Weight of the ``pits`` term against the others; 0 leaves it out (and uncomputed).
    """

    def __init__(self, train_inputs: torch.Tensor, *, margin: float = 0.05, energy_margin: float = 0.1,
                 hole_margin: float = 0.0, pit_weight: float = 0.0) -> None:
        values = (margin, energy_margin, hole_margin, pit_weight)
        if not all(math.isfinite(v) and v >= 0 for v in values):
            raise ValueError(f"margin, energy_margin, hole_margin and pit_weight must be finite and ≥ 0, got "
                             f"{values}")
        self.margin = margin
        self.hole_margin = hole_margin
        self.pit_weight = pit_weight
        self._window = torch.from_numpy(np.array(window_valid_mask()))  # (21 slots, 21 θh, θd)
        self._cells = torch.from_numpy(np.array(cell_valid_mask()))  # (21, θd)
        self._near = torch.from_numpy(np.array(entry_valid_mask()[:, _NEAR, :]))  # (21, 2, θd)
        self._weights = torch.from_numpy(np.array(albedo_weights(), dtype=np.float32))  # (21, θh, θd)
        largest = 0.0
        with torch.no_grad():
            for start in range(0, len(train_inputs), 8):
                chunk = _blocks(train_inputs[start : start + 8].float().cpu())
                largest = max(largest, float(_albedo(chunk, self._weights).max()))
        self.albedo_limit = largest * (1.0 + energy_margin)
        if not self.albedo_limit > 0:
            raise ValueError("the training materials reflect no energy: cannot set an albedo limit")

    def to(self, device: torch.device | str) -> TraversalPenalty:
        """Keep the penalty's fixed masks and weights on ``device`` (the training device), so that a step does not
        copy them there; returns ``self``."""
        self._cells, self._near, self._weights, self._window = (
            t.to(device) for t in (self._cells, self._near, self._weights, self._window))
        return self

    def _pits(self, out: torch.Tensor, src: torch.Tensor) -> torch.Tensor:
        """The ``pits`` term per sample (unweighted) of floored output blocks ``out`` against ``src``."""
        window = self._window.to(out.device)
        edited, allowed = _falls(out.clamp(min=0.0), window), _falls(src, window)
        depth = allowed.amax(dim=-2, keepdim=True).clamp(min=0.0) + self.margin  # the material's own, per cell
        return torch.relu(edited - depth).flatten(1).sum(1)

    def __call__(self, edited: torch.Tensor, material: torch.Tensor) -> TraversalTerms:
        """Penalties of unbounded traversed decodes ``edited`` against the batch's materials.

        Parameters
        ----------
        edited : Tensor, shape (B, 63, 90, 90)
            Decoder output before the clamp, at the traversed codes.
        material : Tensor, shape (B, 63, 90, 90)
            The mapped materials the batch shows (the decoder's targets).

        Returns
        -------
        TraversalTerms
        """
        # In float32 whatever the decoder's dtype: the albedo's exponentials overflow float16.
        device, dtype = edited.device, torch.float32
        cells = self._cells.to(device)
        near_valid = self._near.to(device)
        out, src = _blocks(edited.to(dtype)), _blocks(material.to(dtype))
        allowed = _deficit(src).clamp(min=0.0) + self.margin
        # Below the floor the clamp makes a whole region black alike: the deficit is judged on the floored output.
        inversion = torch.relu(_deficit(out.clamp(min=0.0)) - allowed) * cells
        flank_lit = out[..., _OFF, :].detach().amax(dim=-2, keepdim=True) > 0
        lit = (src[..., _NEAR, :] > 0) & flank_lit & near_valid
        floor = src[..., _NEAR, :].clamp(max=self.hole_margin)
        holes = torch.relu(floor - out[..., _NEAR, :]) * lit
        # Above MAPPED_MAX the decode saturates, and a clamp there would hide the peaks that carry the energy.
        albedo = _albedo(out, self._weights.to(device=device, dtype=dtype), ENERGY_CEILING).clamp(min=1e-12)
        energy = torch.relu(torch.log(albedo) - math.log(self.albedo_limit)).sum(dim=1) * ENERGY_SCALE
        pits = (self.pit_weight * self._pits(out, src) if self.pit_weight > 0
                else torch.zeros_like(energy))
        return TraversalTerms(inversion=inversion.flatten(1).sum(1), holes=holes.flatten(1).sum(1), energy=energy,
                              pits=pits)
