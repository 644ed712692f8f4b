"""The projection algebra of layered records: which records carry a projected base.

Part of :mod:`brdfcodec.codec`, which re-exports the public names.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from brdfcodec.conventions import NETWORK_INPUT_SHAPE
from brdfcodec.format.bvae import (
    Record,
)

if TYPE_CHECKING:
    from brdfcodec.layers.basis import SharedBasis


__all__ = []


@dataclass(frozen=True)
class _ProjectionPlan:
    """Precomputed terms of a projected base's dot products ``aⱼ = (y − m) · vⱼ``, j < P (format 1.6).

    On the basis' entries the clamped decode is y = u + δ, and the unclamped output is
    u = m + W⋆h + b + z·C (the last transposed convolution W of the hidden activations h, its bias b, and
    the linear path: the mean m and the components C). So aⱼ = (Wᵀvⱼ)·h + b·vⱼ + z·(C vⱼ) + δ·vⱼ, where Wᵀ,
    the adjoint of the transposed convolution, is a convolution with the same weights. ``adjoint`` holds
    Wᵀvⱼ for every vector of the basis (K × 32·45·45, a sixth of the vectors' size; a record that projects
    on P vectors uses the first P rows), ``bias`` b·vⱼ, ``linear`` C vⱼ; δ is 0 except where the clamp acted.
    """

    adjoint: np.ndarray  # (K, C·45·45) float32, one row per basis vector
    bias: np.ndarray  # (K,)
    linear: np.ndarray  # (latent_dim, K)
    basis: SharedBasis
    centre: np.ndarray  # (E,)

    @classmethod
    def build(cls, network: torch.nn.Module, basis: SharedBasis, centre: np.ndarray) -> _ProjectionPlan:
        count = basis.count
        last = network.upsample[-1]
        weight = last.weight.detach().float().cpu()
        grid_size = int(np.prod(NETWORK_INPUT_SHAPE))
        adjoint = []
        with torch.no_grad():
            for start in range(0, count, 8):  # 8 vectors on the grid at a time: 16 MB each
                grid = torch.zeros(min(8, count - start), grid_size)
                grid[:, torch.from_numpy(np.array(basis.entries))] = torch.from_numpy(np.array(
                    basis.vectors_uncached(start, min(8, count - start))))
                pulled = torch.nn.functional.conv2d(grid.view(-1, *NETWORK_INPUT_SHAPE), weight,
                                                    stride=last.stride, padding=last.padding)
                adjoint.append(pulled.flatten(1).numpy())
        channel_bias = last.bias.detach().float().cpu().numpy()
        plane = NETWORK_INPUT_SHAPE[1] * NETWORK_INPUT_SHAPE[2]
        bias = basis.dots(channel_bias[basis.entries // plane], count)
        index = network.valid_index.cpu().numpy()
        position = np.searchsorted(index, basis.entries)
        components = network.basis_components.float().cpu().numpy()[:, position]
        return cls(np.concatenate(adjoint), bias.astype(np.float32), basis.dots(components, count).astype(np.float32),
                   basis, np.asarray(centre, dtype=np.float32))

    def reconstruct(self, weights: np.ndarray) -> np.ndarray:
        """``centre + Σⱼ weightsⱼ vⱼ`` over the entries, on the calling thread: right after the network, torch's
        worker threads still spin on the other cores, and a second thread here ran slower than one."""
        out = self.basis.weighted_sum(weights)
        out += self.centre
        return out

    def dot_products(self, count: int, hidden: np.ndarray, z: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """aⱼ, j < ``count``, for one material: ``hidden`` flat (C·45·45,), ``z`` (latent_dim,), ``moved`` = δ
        on the entries."""
        a = self.adjoint[:count] @ hidden + self.bias[:count] + np.asarray(z, dtype=np.float32) @ self.linear[:, :count]
        where = np.flatnonzero(moved)
        if where.size:
            a += self.basis.vector_values(count, where) @ moved[where]
        return a


def _projected_vectors(record: Record) -> int:
    """P of a record whose base decode is projected on the shared basis (format 1.6), else 0."""
    layer = getattr(record, "basis", None)
    return 0 if layer is None else int(layer.project)


def _has_latent(record: Record) -> bool:
    """False for a basis-only record (format 2.1, ``layers.mu = "none"``), whose base is the linear-path mean."""
    return bool(getattr(record, "has_latent", True))


