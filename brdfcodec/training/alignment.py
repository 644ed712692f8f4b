"""Align a trained model's latent axes with the analytic factors of appearance (issue 41).

:func:`align_to_factors` encodes analytic materials with known factors and folds the rotation of
:func:`brdfcodec.models.alignment.factor_rotation` into the model (:func:`~brdfcodec.models.alignment.rotate_latent`).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.models.alignment import (
    ALIGNMENT_MATERIALS,
    ALIGNMENT_SEED,
    AlignmentError,
    FactorAlignment,
    factor_rotation,
    rotate_latent,
)
from brdfcodec.models.network import BetaVAE, Encoder

__all__ = ["align_to_factors", "factor_codes"]


def factor_codes(encoder: Encoder, count: int, seed: int, *, batch_size: int = 16
                 ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], tuple[str, ...]]:
    """Encoder means of ``count`` analytic factor materials and their factors.

    Returns
    -------
    codes : ndarray, shape (count, D)
    factors : ndarray, shape (count, F)
    names : tuple of str
        The factors' names.
    """
    from brdfcodec.datasets.analytic import sample_factor_materials

    drawn = sample_factor_materials(count, seed=seed)
    parameter = next(encoder.parameters())
    codes = []
    for start in range(0, count, batch_size):
        batch = np.stack([m.kept_network_input()[0] for m in drawn.materials[start : start + batch_size]])
        mu, _ = encoder(torch.from_numpy(batch).to(device=parameter.device, dtype=parameter.dtype))
        codes.append(mu.double().cpu().numpy())
    return np.concatenate(codes), drawn.factors, drawn.names


@torch.no_grad()
def align_to_factors(model: BetaVAE, *, materials: int = ALIGNMENT_MATERIALS, seed: int = ALIGNMENT_SEED,
                     rotate: bool = True) -> FactorAlignment:
    """Rotate ``model``'s latent space (in place) so that its dimensions follow the analytic factors.

    Parameters
    ----------
    model : BetaVAE
        Any device; put in evaluation mode for the encoding and left so.
    materials : int, default :data:`ALIGNMENT_MATERIALS`
        Analytic factor materials to fit the rotation to; more than the latent size.
    seed : int, default :data:`ALIGNMENT_SEED`
        Their seed.
    rotate : bool, default True
        Turn the latent; False measures how the present axes follow the factors (identity rotation), for a
        model fine-tuned from an aligned one.

    Returns
    -------
    FactorAlignment
        The rotation applied and how well each aligned dimension follows its factor.
    """
    if materials <= model.config.latent_dim:
        raise AlignmentError(f"an alignment needs more than {model.config.latent_dim} materials, got {materials}")
    model.eval()
    codes, factors, names = factor_codes(model.encoder, materials, seed)
    rotation = factor_rotation(codes, factors) if rotate else np.eye(codes.shape[1])
    if rotate:
        rotate_latent(model.encoder, model.decoder, rotation)
    aligned = codes @ rotation.T
    correlation = np.array([np.corrcoef(aligned[:, i], factors[:, i])[0, 1] for i in range(factors.shape[1])])
    return FactorAlignment(rotation, tuple(names), correlation, materials, seed)
