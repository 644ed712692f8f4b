"""PCA of mapped network inputs: the classic data-driven baseline, and the linear start of ``linear_basis`` models.

One fit serves both: the report's and the model card's PCA baseline
(:func:`fit_pca` on all entries) and the linear path of a ``linear_basis``
β-VAE (:func:`brdfcodec.models.network.initialise_linear_basis`, on the
entries above the horizon), as ``spec/model.md`` describes.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> inputs = rng.random((6, 63, 90, 90)).astype(np.float32)
>>> basis = fit_pca(inputs, 3)
>>> basis.n_components, basis.encode(inputs).shape, basis.decode(basis.encode(inputs)).shape
(3, (6, 3), (6, 63, 90, 90))
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_CHANNELS, NETWORK_INPUT_SHAPE

__all__ = ["PcaBasis", "fit_pca", "fit_pca_colour_orders"]


@dataclass(frozen=True)
class PcaBasis:
    """Mean and orthonormal components of flattened mapped inputs.

    Attributes
    ----------
    mean : ndarray, shape (E,)
        E = 63·90·90 entries, or the number of ``entries`` the basis was fitted on.
    components : ndarray, shape (k, E)
        Rows are orthonormal.
    scale : ndarray, shape (k,)
        Standard deviation of each coefficient over the fitted inputs (> 0).
    entries : ndarray of int or None
        Flat positions (in a 63·90·90 input) the basis covers; all when None.
    """

    mean: npt.NDArray[np.float32]
    components: npt.NDArray[np.float32]
    scale: npt.NDArray[np.float32]
    entries: npt.NDArray[np.int64] | None = None

    @property
    def n_components(self) -> int:
        """Number of components k (the latent size)."""
        return int(self.components.shape[0])

    def encode(self, inputs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Coefficients ``(N, k)`` of inputs ``(N, 63, 90, 90)``."""
        flat = np.asarray(inputs, dtype=np.float32).reshape(len(inputs), -1)
        if self.entries is not None:
            flat = flat[:, self.entries]
        return (flat - self.mean) @ self.components.T

    def decode(self, codes: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Mapped slices ``(N, 63, 90, 90)`` from coefficients, not clamped (entries outside the basis are 0).

        Turn them into tables with
        :func:`~brdfcodec.representation.table_from_network_output`, which
        clamps to the mapped domain.
        """
        flat = np.asarray(codes, dtype=np.float32) @ self.components + self.mean
        if self.entries is not None:
            full = np.zeros((len(flat), int(np.prod(NETWORK_INPUT_SHAPE))), dtype=np.float32)
            full[:, self.entries] = flat
            flat = full
        return flat.reshape(-1, *NETWORK_INPUT_SHAPE)


def fit_pca(inputs: npt.ArrayLike, n_components: int, *, entries: Sequence[int] | np.ndarray | None = None) -> PcaBasis:
    """Fit a PCA basis to mapped inputs (SVD in float64).

    Parameters
    ----------
    inputs : array_like, shape (N, 63, 90, 90)
        Training inputs (invalid entries 0, as in datasets).
    n_components : int
        k, in [1, N].
    entries : sequence of int, optional
        Flat positions to fit on (e.g. the entries above the horizon); all by default.

    Returns
    -------
    PcaBasis
    """
    flat = np.asarray(inputs, dtype=np.float64).reshape(len(inputs), -1)
    chosen = None if entries is None else np.asarray(entries, dtype=np.int64)
    if chosen is not None:
        flat = flat[:, chosen]
    if not 1 <= n_components <= flat.shape[0]:
        raise ValueError(f"n_components must be in [1, {flat.shape[0]}], got {n_components}")
    mean = flat.mean(axis=0)
    _, singular, vt = np.linalg.svd(flat - mean, full_matrices=False)
    scale = np.maximum(singular[:n_components] / max(1, flat.shape[0] - 1) ** 0.5, 1e-12)
    return PcaBasis(mean.astype(np.float32), vt[:n_components].astype(np.float32), scale.astype(np.float32), chosen)


def fit_pca_colour_orders(inputs: npt.ArrayLike, n_components: int) -> PcaBasis:
    """Fit a PCA basis to mapped inputs taken in all 6 orders of their colour channels (all entries).

    The same basis as :func:`fit_pca` of
    :func:`~brdfcodec.layers.basis.with_colour_permutations` ``(inputs)``, up to
    rotations within pairs of equal singular values, found without making the
    6N permuted inputs (:func:`~brdfcodec.layers.colour_orders_pca.colour_orders_pca`).

    Parameters
    ----------
    inputs : array_like, shape (N, 63, 90, 90)
        Training inputs (invalid entries 0, as in datasets).
    n_components : int
        k, in [1, 5N − 1].

    Returns
    -------
    PcaBasis
        ``scale`` is each coefficient's standard deviation over the 6N permuted inputs.
    """
    from brdfcodec.layers.colour_orders_pca import colour_orders_pca

    x = np.asarray(inputs)
    n = len(x)
    if not 1 <= n_components <= 5 * n - 1:
        raise ValueError(f"n_components must be in [1, {5 * n - 1}], got {n_components}")
    pca = colour_orders_pca(x.reshape(n, N_CHANNELS, -1), n_components)
    scale = np.maximum(pca.singular / max(1, 6 * n - 1) ** 0.5, 1e-12)
    return PcaBasis(pca.mean.astype(np.float32), pca.components.astype(np.float32), scale.astype(np.float32))
