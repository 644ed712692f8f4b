"""Principal components of materials in all 6 orders of their colour channels, without making the 6 orders.

A basis fitted on the training materials in every order of their (R, G, B)
channels spans colours the training set lacks (the shared basis of
``bvae model export`` and the report's ``pca-perm`` baseline). Those 6N
materials need not be made: their covariance commutes with every
permutation of the colours, so each principal component is a vector over
one colour's entries times a colour vector, and they split in two kinds:

- **grey** components ``u ⊗ (1, 1, 1)/√3``: the principal components ``u``
  of the N materials' colour sums ``s = x_R + x_G + x_B`` (centred), with
  singular values ``√2 · σ(s)``;
- **chroma** components ``u ⊗ e``, two for each ``u``, with ``e`` the
  orthonormal sum-zero colour vectors ``(1, −1, 0)/√2`` and
  ``(1, 1, −2)/√6``: the principal components of the 3N colour deviations
  ``x_c − s/3`` (not centred: their mean over the 6 orders is 0), with
  singular values ``√3 · σ`` each (a degenerate pair).

So the fit takes an SVD of N + 3N rows over a third of the entries instead
of 6N rows over all of them (a sixth of the memory, for 76 training
materials 0.3 GB instead of 1.9 GB in float64), and finds the same
components up to rotations within each degenerate pair. The count is at
most (N − 1) + 2 · 2N = 5N − 1 (the chroma deviations of one material sum to
0, so they span at most 2N dimensions): the rank of the permuted data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_CHANNELS

__all__ = ["COLOUR_VECTORS", "ColourOrdersPca", "colour_orders_pca"]

#: Orthonormal colour vectors: grey, then the two sum-zero (chroma) directions.
_GREY = np.full(N_CHANNELS, 1.0 / np.sqrt(3.0))
_CHROMA = (np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0), np.array([1.0, 1.0, -2.0]) / np.sqrt(6.0))
#: The colour vector of each kind of component: index 0 grey, 1 and 2 the chroma directions.
COLOUR_VECTORS = np.stack([_GREY, *_CHROMA])


@dataclass(frozen=True)
class ColourOrdersPca:
    """Principal components of materials taken in all 6 colour orders.

    Attributes
    ----------
    mean : ndarray of float64, shape (3P,)
        Mean over the 6N permuted materials (grey: the mean colour sum / 3 in every colour).
    components : ndarray of float64, shape (K, 3P)
        Orthonormal rows, colour-major (entries ``c·P … (c+1)·P − 1`` belong to colour c), by
        descending singular value.
    singular : ndarray of float64, shape (K,)
        Singular values of the centred 6N × 3P data along each component.
    colours : ndarray of int64, shape (K,)
        Each component's colour vector (a row of :data:`COLOUR_VECTORS`: 0 grey, 1 or 2 chroma).
    factors : ndarray of float64, shape (F, P)
        The distinct per-colour vectors ``u`` (a chroma pair shares one).
    factor_of : ndarray of int64, shape (K,)
        Each component's row of ``factors``: component k is ``COLOUR_VECTORS[colours[k]] ⊗ factors[factor_of[k]]``.
    """

    mean: npt.NDArray[np.float64]
    components: npt.NDArray[np.float64]
    singular: npt.NDArray[np.float64]
    colours: npt.NDArray[np.int64]
    factors: npt.NDArray[np.float64]
    factor_of: npt.NDArray[np.int64]


def colour_orders_pca(values: npt.ArrayLike, count: int | None = None) -> ColourOrdersPca:
    """PCA of N materials in all 6 orders of their colour channels.

    Parameters
    ----------
    values : array_like, shape (N, 3, P)
        Each material's entries per colour (the same P entries in every colour; mapped units).
    count : int, optional
        Components to keep, at most 5N − 1 (the most the permuted data can span); 5N − 1 by default.
        Past the data's own rank (grey materials have no chroma) the singular values are 0 and the
        components are orthonormal directions the data does not use.

    Returns
    -------
    ColourOrdersPca

    Examples
    --------
    >>> import itertools
    >>> rng = np.random.default_rng(0)
    >>> x = rng.random((4, 3, 50))
    >>> pca = colour_orders_pca(x)
    >>> permuted = np.concatenate([x[:, list(o)] for o in itertools.permutations(range(3))]).reshape(24, 150)
    >>> bool(np.allclose(pca.singular, np.linalg.svd(permuted - permuted.mean(0), compute_uv=False)[:19]))
    True
    """
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 3 or x.shape[1] != N_CHANNELS or len(x) == 0:
        raise ValueError(f"expected values of shape (N, {N_CHANNELS}, P) with N >= 1, got {x.shape}")
    n, _, p = x.shape
    sums = x.sum(axis=1)
    mean_sum = sums.mean(axis=0)
    _, s_grey, u_grey = np.linalg.svd(sums - mean_sum, full_matrices=False)
    deviations = (x - sums[:, None, :] / N_CHANNELS).reshape(n * N_CHANNELS, p)
    del sums
    _, s_chroma, u_chroma = np.linalg.svd(deviations, full_matrices=False)
    del deviations
    # (singular value, kind, row): grey rows once, chroma rows twice (one per sum-zero colour vector).
    found = [(np.sqrt(2.0) * s, -1, i) for i, s in enumerate(s_grey)]
    found += [(np.sqrt(3.0) * s, j, i) for i, s in enumerate(s_chroma) for j in range(2)]
    found.sort(key=lambda f: (-f[0], f[2], f[1]))
    rank = min(5 * n - 1, len(found))
    if count is None:
        count = rank
    if not 0 <= count <= rank:
        raise ValueError(f"count must be in [0, {rank}] (5N − 1 for N = {n} materials, at most), got {count}")
    components = np.empty((count, N_CHANNELS * p))
    factor_rows: dict[tuple[bool, int], int] = {}  # (grey, row of its SVD) → row of `factors`
    colours, factor_of, factors = [], [], []
    for row, (_, kind, i) in enumerate(found[:count]):
        source = u_grey[i] if kind < 0 else u_chroma[i]
        components[row] = np.kron(COLOUR_VECTORS[kind + 1], source)
        key = (kind < 0, i)
        if key not in factor_rows:
            factor_rows[key] = len(factors)
            factors.append(source)
        colours.append(kind + 1)
        factor_of.append(factor_rows[key])
    mean = np.tile(mean_sum / N_CHANNELS, N_CHANNELS)
    return ColourOrdersPca(mean, components, np.array([f[0] for f in found[:count]]),
                           np.array(colours, dtype=np.int64),
                           np.array(factors).reshape(len(factors), p), np.array(factor_of, dtype=np.int64))
