"""Align a latent space with named factors of appearance: one orthogonal rotation (issue 41).

A β-VAE's prior N(0, I) is the same in every orthonormal frame, so which
directions of its latent space are *the* dimensions is not fixed by the
objective: training picks one frame by accident. This module picks it on
purpose. It encodes analytic materials whose generating factors are known and
drawn independently (:func:`brdfcodec.datasets.analytic.sample_factor_materials`:
albedo, hue, specular, roughness, grazing, sheen, metallic), and finds the
rotation ``R`` (orthogonal Procrustes) that makes the i-th rotated code
``z'_i = (R z)_i`` covary most with the i-th factor, summed over factors:
``R = V Uᵀ`` for the SVD ``U S Vᵀ`` of the cross-covariance of the centred codes and the
standardised factors. Dimensions beyond the factors take the remaining
directions in order of their variance over the materials.

(:func:`brdfcodec.training.alignment.align_to_factors` encodes them and
rotates a model.) The rotation is folded into the weights (:func:`rotate_latent`): the encoder's μ
head and linear projection become ``R ·``, the decoder's first layer and linear
path ``· Rᵀ``, so every material decodes as before (up to the float16 rounding
of the rotated linear path) and only what each slider moves changes. The
encoder's log σ² head becomes ``(R ∘ R) ·``: log σ'² is the weighted mean of the
log σ² it mixes, a lower bound of the rotated posterior's variance (which is
not diagonal); the posterior σ carries little information in these models
(model card, "Posterior").

The materials are drawn with :data:`ALIGNMENT_SEED`, not the disentanglement
benchmark's default seed 0 (:mod:`brdfcodec.report.disentanglement`), so the
benchmark scores an alignment on materials it was not fitted to.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.errors import BrdfcodecError
from brdfcodec.models.network import Decoder, Encoder

__all__ = [
    "ALIGNMENT_MATERIALS",
    "ALIGNMENT_SEED",
    "AlignmentError",
    "FactorAlignment",
    "factor_rotation",
    "rotate_latent",
]

#: Seed of the analytic materials an alignment is fitted to (the disentanglement benchmark's default is 0).
ALIGNMENT_SEED = 1
#: Analytic materials an alignment is fitted to by default.
ALIGNMENT_MATERIALS = 300


class AlignmentError(BrdfcodecError, ValueError):
    """Codes and factors that cannot define an alignment (shapes, too few materials, non-finite values)."""


@dataclass(frozen=True)
class FactorAlignment:
    """One alignment of a latent space with named factors.

    Attributes
    ----------
    rotation : ndarray of float64, shape (D, D)
        Orthogonal; the aligned code is ``rotation @ z``.
    factor_names : tuple of str
        Factor aligned with each of the first ``len(factor_names)`` aligned dimensions.
    correlation : ndarray of float64, shape (len(factor_names),)
        Pearson correlation of aligned dimension i with factor i over the fitted materials, in [−1, 1].
    materials, seed : int
        The analytic materials the rotation was fitted to (:func:`align_to_factors`).
    """

    rotation: npt.NDArray[np.float64]
    factor_names: tuple[str, ...]
    correlation: npt.NDArray[np.float64]
    materials: int
    seed: int

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (stored as ``info.alignment`` of an exported model)."""
        return {"rotation": self.rotation.tolist(), "factor_names": list(self.factor_names),
                "correlation": [float(c) for c in self.correlation], "materials": self.materials,
                "seed": self.seed}


def factor_rotation(codes: npt.ArrayLike, factors: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The orthogonal rotation that aligns code dimension i with factor i (orthogonal Procrustes).

    Parameters
    ----------
    codes : array_like, shape (N, D)
        Latent codes (encoder means) of N materials.
    factors : array_like, shape (N, F), F ≤ D
        Their generating factors, any units (each is standardised).

    Returns
    -------
    ndarray of float64, shape (D, D)
        Orthogonal ``R`` maximising Σᵢ cov((R z)ᵢ, fᵢ / std fᵢ); rows F to D − 1 span what is left of
        the code space, in decreasing order of the codes' variance, each signed so that its largest
        component is positive.

    Raises
    ------
    AlignmentError
        Shapes disagree, F > D, fewer than D + 1 materials, non-finite values or a constant factor.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> factors = rng.random((200, 2))
    >>> turn = np.array([[0.0, -1.0], [1.0, 0.0]])  # codes are the factors turned by 90°
    >>> rotation = factor_rotation(factors @ turn.T, factors)
    >>> bool(np.abs(rotation @ turn - np.eye(2)).max() < 0.01)  # turned back (up to sampling noise)
    True
    """
    z = np.asarray(codes, dtype=np.float64)
    f = np.asarray(factors, dtype=np.float64)
    if z.ndim != 2 or f.ndim != 2 or len(z) != len(f):
        raise AlignmentError(f"codes (N, D) and factors (N, F) must have the same N, got {z.shape} and {f.shape}")
    n, dims = z.shape
    if f.shape[1] > dims:
        raise AlignmentError(f"{f.shape[1]} factors cannot be aligned with {dims} code dimensions")
    if n <= dims:
        raise AlignmentError(f"an alignment of {dims} dimensions needs more than {dims} materials, got {n}")
    if not (np.isfinite(z).all() and np.isfinite(f).all()):
        raise AlignmentError("codes and factors must be finite")
    spread = f.std(axis=0)
    if (spread <= 0).any():
        raise AlignmentError("every factor must vary over the materials")
    centred = z - z.mean(axis=0)
    cross = centred.T @ ((f - f.mean(axis=0)) / spread)  # (D, F)
    left, _, right_t = np.linalg.svd(cross, full_matrices=True)  # left (D, D), right_t (F, F)
    aligned = right_t.T @ left[:, : f.shape[1]].T  # (F, D): rows maximise the summed covariances
    rest = left[:, f.shape[1]:]  # (D, D − F): orthonormal complement of the aligned rows
    if rest.shape[1]:
        variance, order = np.linalg.eigh(np.cov((centred @ rest).T, ddof=1).reshape(rest.shape[1], -1))
        rest_rows = (rest @ order[:, np.argsort(variance)[::-1]]).T
        signs = np.sign(rest_rows[np.arange(len(rest_rows)), np.abs(rest_rows).argmax(axis=1)])
        aligned = np.concatenate([aligned, rest_rows * signs[:, None]])
    return aligned


def _rotate_rows(weight: torch.Tensor, matrix: torch.Tensor) -> torch.Tensor:
    return (matrix @ weight.double()).to(weight.dtype)


@torch.no_grad()
def rotate_latent(encoder: Encoder | None, decoder: Decoder | None, rotation: npt.ArrayLike) -> None:
    """Fold an orthogonal rotation of the latent space into an encoder and a decoder, in place.

    Parameters
    ----------
    encoder, decoder : Encoder or Decoder or None
        The parts to rotate (None: leave it out); their latent size D.
    rotation : array_like, shape (D, D)
        Orthogonal to 1e-6; the new code is ``rotation @ z``.

    Raises
    ------
    AlignmentError
        Not D × D or not orthogonal.
    """
    matrix = torch.as_tensor(np.asarray(rotation, dtype=np.float64))
    part = encoder if encoder is not None else decoder
    if part is None:
        return
    dims = part.config.latent_dim
    if matrix.shape != (dims, dims):
        raise AlignmentError(f"a rotation of a {dims}-D latent must be {dims} × {dims}, got {tuple(matrix.shape)}")
    if not torch.allclose(matrix @ matrix.T, torch.eye(dims, dtype=torch.float64), atol=1e-6):
        raise AlignmentError("the rotation must be orthogonal")
    if encoder is not None:
        head = encoder.head
        head.weight[:dims] = _rotate_rows(head.weight[:dims], matrix)
        head.bias[:dims] = _rotate_rows(head.bias[:dims, None], matrix)[:, 0]
        squares = matrix * matrix  # log σ'² = Σ_j R_ij² log σ_j²: rows sum to 1
        head.weight[dims:] = _rotate_rows(head.weight[dims:], squares)
        head.bias[dims:] = _rotate_rows(head.bias[dims:, None], squares)[:, 0]
        if encoder.config.linear_basis:
            encoder.basis_projection.copy_(_rotate_rows(encoder.basis_projection, matrix))
    if decoder is not None:
        first = decoder.fc[0]
        first.weight.copy_((first.weight.double() @ matrix.T).to(first.weight.dtype))
        if decoder.config.linear_basis:
            decoder.basis_components.copy_(_rotate_rows(decoder.basis_components, matrix))
