"""The β-VAE objective (paper, §Implementation Details), with its reductions stated.

Per material i of a batch of B::

    recon_i = Σ_valid entries  e(x̃ − x)        e = squared error ("l2") or absolute error ("l1")
    KL_i    = Σ_j −½ (1 + log σ²_j − μ²_j − σ²_j)      over the M latent dimensions
    loss    = (1/B) Σ_i (recon_i + β_norm · KL_i),      β_norm = β · M / N

with N = 63·90·90 the input size. The reconstruction is a *sum* over valid
entries (the paper's ‖mask(x̃) − mask(x)‖, squared for "l2"); the batch
reduction is a mean. β = 12 in the paper.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch

from brdfcodec.conventions import NETWORK_INPUT_SHAPE

__all__ = ["LossTerms", "beta_norm", "beta_vae_loss", "kl_per_dimension", "latent_rate", "masked_recon_per_sample"]

ReconKind = Literal["l2", "l1"]
_N_INPUT = NETWORK_INPUT_SHAPE[0] * NETWORK_INPUT_SHAPE[1] * NETWORK_INPUT_SHAPE[2]


@dataclass(frozen=True)
class LossTerms:
    """Batch means of the objective and its parts (tensors, for backward and logging)."""

    loss: torch.Tensor
    recon: torch.Tensor
    kl: torch.Tensor


def beta_norm(beta: float, latent_dim: int) -> float:
    """β · M / N, the KL weight against a reconstruction summed over N entries."""
    return beta * latent_dim / _N_INPUT


def kl_per_dimension(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(N(μ, σ²) ‖ N(0, 1)) per sample and dimension, shape (B, M), in nats."""
    return -0.5 * (1.0 + logvar - mu.pow(2) - logvar.exp())


def latent_rate(noisy_mu: torch.Tensor, step: float) -> torch.Tensor:
    """Code length of μ on a grid under the format's unit Laplace prior, in nats, per sample and dimension.

    The coded μ of ``spec/bvae-format.md`` §4.9 is the integer ``round(μ/Δ)``
    under a zero-mean Laplace prior of spread one latent unit (scale
    b = 1/√2); its code length is −ln P, P the prior's mass on the cell
    ``[qΔ − Δ/2, qΔ + Δ/2]``. In training the rounding is replaced by
    additive uniform noise (``noisy_mu = μ + Δ·u``, u ~ U(−½, ½)), whose
    mass on the cell of width Δ centred on it is a differentiable proxy of
    that length (as in learned image compression).

    Parameters
    ----------
    noisy_mu : Tensor, shape (B, M)
        μ plus uniform noise of width ``step``, latent units.
    step : float
        Δ = 2^−g, the grid's step, latent units (> 0).

    Returns
    -------
    Tensor, shape (B, M)
        −ln P, nats, finite (P is floored at 1e-12).
    """
    if not step > 0:
        raise ValueError(f"step must be > 0, got {step}")
    scale = 0.5**0.5
    # Mirror every value into the lower tail (the prior is symmetric): the cell's lower edge is then below 0,
    # where the CDF is ½·exp(t/b) without cancellation.
    centre = -noisy_mu.abs()
    lower = 0.5 * torch.exp((centre - 0.5 * step) / scale)
    upper_edge = centre + 0.5 * step
    upper = torch.where(upper_edge <= 0, 0.5 * torch.exp(upper_edge.clamp_max(0.0) / scale),
                        1.0 - 0.5 * torch.exp(-upper_edge.clamp_min(0.0) / scale))
    return -torch.log((upper - lower).clamp_min(1e-12))


def masked_recon_per_sample(reconstruction: torch.Tensor, target: torch.Tensor, mask: torch.Tensor,
                            recon: ReconKind = "l2") -> torch.Tensor:
    """Each material's reconstruction error, summed over its valid entries.

    Parameters
    ----------
    reconstruction, target : Tensor, shape (B, 63, 90, 90)
        Decoder output and input, mapped.
    mask : Tensor of bool, shape (B, 63, 90, 90)
        Valid entries; the others never contribute.
    recon : {"l2", "l1"}
        Squared error or absolute error.

    Returns
    -------
    Tensor, shape (B,)
        ≥ 0, mapped units (squared for ``"l2"``).
    """
    difference = (reconstruction - target) * mask
    if recon == "l2":
        per_entry = difference.pow(2)
    elif recon == "l1":
        per_entry = difference.abs()
    else:
        raise ValueError(f"recon must be 'l2' or 'l1', got {recon!r}")
    return per_entry.flatten(1).sum(dim=1)


def beta_vae_loss(
    reconstruction: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor,
    mu: torch.Tensor,
    logvar: torch.Tensor,
    *,
    beta: float,
    recon: ReconKind = "l2",
) -> LossTerms:
    """The masked β-VAE loss.

    Parameters
    ----------
    reconstruction, target : Tensor, shape (B, 63, 90, 90)
        Decoder output and input, mapped.
    mask : Tensor of bool, shape (B, 63, 90, 90)
        Valid entries; the others never contribute.
    mu, logvar : Tensor, shape (B, M)
        Posterior parameters.
    beta : float
        β (12 in the paper); β_norm = β·M/N multiplies the KL.
    recon : {"l2", "l1"}
        Squared error (paper) or absolute error (matches RelAE).

    Returns
    -------
    LossTerms
    """
    recon_per_sample = masked_recon_per_sample(reconstruction, target, mask, recon)
    kl_per_sample = kl_per_dimension(mu, logvar).sum(dim=1)
    weight = beta_norm(beta, mu.shape[1])
    loss = (recon_per_sample + weight * kl_per_sample).mean()
    return LossTerms(loss=loss, recon=recon_per_sample.mean(), kl=kl_per_sample.mean())
