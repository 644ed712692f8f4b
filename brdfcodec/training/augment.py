"""Training-time augmentation of mapped inputs, physically meaningful.

Both operate on batches in the network layout ``(B, 63, 90, 90)`` whose
channel ``k`` is colour ``k // 21`` (``spec/conventions.md`` §6):

- *colour permutation*: exchange the R, G, B reflectances of a material.
  Since the mapping is the same function of reflectance in every channel,
  permuting mapped channels permutes reflectances exactly. It shows the
  network colours (greens above all) that the measured set lacks.
- *physical mixing*: ``t·ρ_a + (1 − t)·ρ_b`` in reflectance, which is a
  valid BRDF (a blend of two materials), mapped back. It fills the space
  between training materials.
"""

from __future__ import annotations

import itertools

import torch

from brdfcodec.conventions import N_CHANNELS, N_KEPT_SLICES
from brdfcodec.representation import LOG_RANGE

__all__ = ["COLOUR_PERMUTATIONS", "mix_physical", "permute_colours"]

#: The 6 orders of (R, G, B); index 0 is the identity.
COLOUR_PERMUTATIONS = torch.tensor(list(itertools.permutations(range(N_CHANNELS))))
_LOG_RANGE = LOG_RANGE


def permute_colours(batch: torch.Tensor, permutation_index: torch.Tensor) -> torch.Tensor:
    """Reorder the colour channels of each material.

    Parameters
    ----------
    batch : Tensor, shape (B, 63, 90, 90)
        Mapped inputs, or masks.
    permutation_index : Tensor of int, shape (B,)
        Row of :data:`COLOUR_PERMUTATIONS` for each material (0 keeps it).
    """
    b, _, h, w = batch.shape
    grouped = batch.view(b, N_CHANNELS, N_KEPT_SLICES, h, w)
    order = COLOUR_PERMUTATIONS.to(batch.device)[permutation_index]  # (B, 3)
    index = order.view(b, N_CHANNELS, 1, 1, 1).expand(-1, -1, N_KEPT_SLICES, h, w)
    return torch.gather(grouped, 1, index).view(b, -1, h, w)


def mix_physical(mapped_a: torch.Tensor, mapped_b: torch.Tensor, weight_a: torch.Tensor) -> torch.Tensor:
    """Mapped values of the reflectance blend ``t·ρ_a + (1 − t)·ρ_b``.

    Parameters
    ----------
    mapped_a, mapped_b : Tensor, shape (B, 63, 90, 90)
        Mapped inputs.
    weight_a : Tensor, shape (B,)
        t in [0, 1] for each pair.
    """
    t = weight_a.view(-1, 1, 1, 1).to(mapped_a.dtype)
    linear_a = torch.expm1(mapped_a * _LOG_RANGE)  # reflectance · S / ε, same factor for a and b
    linear_b = torch.expm1(mapped_b * _LOG_RANGE)
    return torch.log1p(t * linear_a + (1 - t) * linear_b) / _LOG_RANGE
