"""Weak supervision of the latent by analytic materials whose generating factors are known (issue 50, item 3).

The analytic materials of :func:`brdfcodec.datasets.analytic.sample_factor_materials` are described by seven
independent factors (albedo, hue, specular, roughness, grazing, sheen, metallic; each uniform in [0, 1]). A run
with ``TrainConfig.factor_weight`` > 0 draws a pool of them (``factor_materials`` of seed ``factor_seed``, a seed
the disentanglement benchmark and the factor alignment do not use), and each optimiser step also encodes
``factor_batch`` of them. Besides their β-VAE objective (they are training materials too), the step adds

    factor_weight · (1/B) Σ_b Σ_j (μ_bj − t_bj)²

where the target ``t_bj`` of the latent dimension j < 7 is factor j standardised, ``(v_j − ½)·√12`` (mean 0,
variance 1, as the prior), and 0 for the dimensions beyond the seventh: without ``factor_saturation`` the family
has no eighth factor, so a free dimension is kept at the prior's mean on it and left to the real materials' other
variation. Dimension j is so tied to factor j alone, in the order of
:data:`~brdfcodec.datasets.analytic.FACTOR_NAMES` (the order of the shipped model's aligned axes, ``model.json``
``info.alignment``).

With ``TrainConfig.factor_saturation`` the pool's colours also vary in saturation (an eighth factor, grey to fully
saturated; without it every colour has saturation 0.7, so a grey or white material is outside the family the
supervision ties the latent to), and dimension 8 is tied to it. The hue of a nearly grey colour is not visible, so
the hue term of a material of saturation s is weighted by min(1, s / 0.7): full at the benchmark's saturation, 0
for grey.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.datasets.analytic import FACTOR_ALPHA_RANGE, FACTOR_SATURATION, SATURATION_FACTOR

__all__ = ["FactorPool", "build_factor_pool", "factor_supervision_loss", "factor_targets", "factor_weights"]

def factor_targets(factors: npt.ArrayLike, latent_dim: int) -> npt.NDArray[np.float32]:
    """The latent targets of materials with known factors.

    Parameters
    ----------
    factors : array_like, shape (N, K)
        Factor values in [0, 1] (K = 7 for :func:`~brdfcodec.datasets.analytic.sample_factor_materials`, 8 with
        its saturation).
    latent_dim : int
        Latent size M ≥ K.

    Returns
    -------
    ndarray of float32, shape (N, M)
        Column j < K: factor j standardised, ``(v − ½)·√12`` (in [−√3, √3], prior σ units);
        columns ≥ K: 0.
    """
    values = np.asarray(factors, dtype=np.float64)
    if values.ndim != 2 or not np.isfinite(values).all() or (values < 0).any() or (values > 1).any():
        raise ValueError(f"factors must be an (N, K) array of values in [0, 1], got shape {values.shape}")
    if latent_dim < values.shape[1]:
        raise ValueError(f"factor supervision needs a latent of at least {values.shape[1]} dimensions (one per "
                         f"factor), got {latent_dim}")
    targets = np.zeros((len(values), latent_dim), dtype=np.float32)
    targets[:, : values.shape[1]] = (values - 0.5) * math.sqrt(12.0)
    return targets


def factor_weights(factors: npt.ArrayLike, names: tuple[str, ...], latent_dim: int) -> npt.NDArray[np.float32]:
    """Per-material weights of each latent dimension's term.

    Parameters
    ----------
    factors : array_like, shape (N, K)
        Factor values in [0, 1], columns ``names``.
    names : tuple of str
        The factors' names (:attr:`~brdfcodec.datasets.analytic.FactorMaterials.names`).
    latent_dim : int
        Latent size M ≥ K.

    Returns
    -------
    ndarray of float32, shape (N, M)
        1, except the hue column when ``saturation`` is a factor: min(1, saturation / 0.7), 0.7 the benchmark's
        saturation (:data:`~brdfcodec.datasets.analytic.FACTOR_SATURATION`).
    """
    values = np.asarray(factors, dtype=np.float64)
    weights = np.ones((len(values), latent_dim), dtype=np.float32)
    if SATURATION_FACTOR in names and "hue" in names:
        saturation = values[:, names.index(SATURATION_FACTOR)]
        weights[:, names.index("hue")] = np.minimum(1.0, saturation / FACTOR_SATURATION)
    return weights


def factor_supervision_loss(mu: torch.Tensor, targets: torch.Tensor, weights: torch.Tensor | None = None
                            ) -> torch.Tensor:
    """Squared distance of the encoder means to their factor targets, summed over dimensions, batch mean.

    Parameters
    ----------
    mu, targets : Tensor, shape (B, M)
        Encoder means and :func:`factor_targets` (prior σ units).
    weights : Tensor, shape (B, M), optional
        :func:`factor_weights`; all 1 when not given.

    Returns
    -------
    Tensor
        A scalar ≥ 0 (prior σ² units).
    """
    if mu.shape != targets.shape or (weights is not None and weights.shape != mu.shape):
        raise ValueError(f"mu, targets and weights must have one shape, got {tuple(mu.shape)}, "
                         f"{tuple(targets.shape)} and {None if weights is None else tuple(weights.shape)}")
    squared = (mu - targets).pow(2)
    return (squared if weights is None else squared * weights).sum(dim=1).mean()


@dataclass
class FactorPool:
    """Analytic materials of known factors, ready for the network.

    Attributes
    ----------
    inputs : Tensor of float32, shape (N, 63, 90, 90)
        Mapped network inputs.
    masks : Tensor of bool, shape (N, 63, 90, 90)
        Valid entries.
    targets : Tensor of float32, shape (N, M)
        :func:`factor_targets`.
    weights : Tensor of float32, shape (N, M)
        :func:`factor_weights`.
    seed : int
        The seed the materials were drawn with.
    factor_count : int
        The family's factors K (7, or 8 with saturation): the first K columns of ``targets`` are factors, the
        others 0.
    """

    inputs: torch.Tensor
    masks: torch.Tensor
    targets: torch.Tensor
    weights: torch.Tensor
    seed: int
    factor_count: int = 7

    def __len__(self) -> int:
        return len(self.inputs)

    def to(self, device: torch.device) -> FactorPool:
        """The pool on ``device`` (in place; returns itself)."""
        self.inputs, self.masks, self.targets, self.weights = (
            t.to(device) for t in (self.inputs, self.masks, self.targets, self.weights))
        return self


def build_factor_pool(count: int, seed: int, latent_dim: int, *, saturation: bool = False,
                      alpha_min: float = FACTOR_ALPHA_RANGE[0]) -> FactorPool:
    """Draw ``count`` factor materials of ``seed`` and tabulate their network inputs (about 0.1 s each).

    Parameters
    ----------
    count : int
        Materials, ≥ 1 (each takes 2 MB of inputs and 0.5 MB of mask in memory).
    seed : int
        Seed of :func:`~brdfcodec.datasets.analytic.sample_factor_materials`.
    latent_dim : int
        Latent size (≥ 7; ≥ 8 with ``saturation``).
    saturation : bool, default False
        Vary the colours' saturation too, an eighth factor tied to dimension 8
        (:func:`~brdfcodec.datasets.analytic.sample_factor_materials`).
    alpha_min : float, default 0.03
        The sharpest GGX α of the roughness factor, in (0, 0.6) (the default is the benchmark's,
        :data:`~brdfcodec.datasets.analytic.FACTOR_ALPHA_RANGE`).

    Returns
    -------
    FactorPool
    """
    from brdfcodec.datasets.analytic import sample_factor_materials

    drawn = sample_factor_materials(count, seed=seed, saturation=saturation, alpha_min=alpha_min)
    targets = torch.from_numpy(factor_targets(drawn.factors, latent_dim))
    weights = torch.from_numpy(factor_weights(drawn.factors, drawn.names, latent_dim))
    first_input, first_mask = drawn.materials[0].kept_network_input()
    inputs = torch.empty((count, *first_input.shape), dtype=torch.float32)
    masks = torch.empty((count, *first_mask.shape), dtype=torch.bool)
    for index, material in enumerate(drawn.materials):
        x, m = (first_input, first_mask) if index == 0 else material.kept_network_input()
        inputs[index], masks[index] = torch.from_numpy(x), torch.from_numpy(m)
    return FactorPool(inputs, masks, targets, weights, seed, factor_count=int(drawn.factors.shape[1]))
