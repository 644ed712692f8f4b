"""PCA of the mapped network inputs: the classic data-driven baseline at equal latent size."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import MAPPED_MAX, NETWORK_INPUT_SHAPE

__all__ = ["PcaBasis", "fit_pca"]


@dataclass(frozen=True)
class PcaBasis:
    """Mean and orthonormal components of flattened mapped inputs.

    Attributes
    ----------
    mean : ndarray, shape (63·90·90,)
    components : ndarray, shape (k, 63·90·90)
        Rows are orthonormal.
    """

    mean: npt.NDArray[np.float32]
    components: npt.NDArray[np.float32]

    @property
    def n_components(self) -> int:
        """Number of components k (the latent size)."""
        return int(self.components.shape[0])

    def encode(self, inputs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Coefficients ``(N, k)`` of inputs ``(N, 63, 90, 90)``."""
        flat = np.asarray(inputs, dtype=np.float32).reshape(len(inputs), -1)
        return (flat - self.mean) @ self.components.T

    def decode(self, codes: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Mapped slices ``(N, 63, 90, 90)`` from coefficients, clamped to the mapped domain."""
        flat = np.asarray(codes, dtype=np.float32) @ self.components + self.mean
        return np.clip(flat, 0.0, MAPPED_MAX).reshape(-1, *NETWORK_INPUT_SHAPE)


def fit_pca(inputs: npt.ArrayLike, n_components: int) -> PcaBasis:
    """Fit a PCA basis to mapped inputs.

    Parameters
    ----------
    inputs : array_like, shape (N, 63, 90, 90)
        Training inputs (invalid entries 0, as in datasets).
    n_components : int
        k, at most N.

    Returns
    -------
    PcaBasis
    """
    flat = np.asarray(inputs, dtype=np.float64).reshape(len(inputs), -1)
    if not 1 <= n_components <= flat.shape[0]:
        raise ValueError(f"n_components must be in [1, {flat.shape[0]}], got {n_components}")
    mean = flat.mean(axis=0)
    _, _, vt = np.linalg.svd(flat - mean, full_matrices=False)
    return PcaBasis(mean.astype(np.float32), vt[:n_components].astype(np.float32))
