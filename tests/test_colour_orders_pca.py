"""PCA of materials in all 6 colour orders, found from colour sums and deviations (brdfcodec.layers.colour_orders_pca)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from brdfcodec.layers.basis import with_colour_permutations
from brdfcodec.layers.colour_orders_pca import colour_orders_pca
from brdfcodec.models.pca import fit_pca, fit_pca_colour_orders


def _permuted(x: np.ndarray) -> np.ndarray:
    return np.concatenate([x[:, list(order)] for order in itertools.permutations(range(3))]).reshape(6 * len(x), -1)


def _projector(rows: np.ndarray) -> np.ndarray:
    return rows.T @ rows


def test_matches_the_svd_of_the_six_colour_orders() -> None:
    rng = np.random.default_rng(3)
    x = rng.random((5, 3, 60)) + rng.random((1, 3, 60))  # a shared colour cast, as real materials have
    data = _permuted(x)
    centred = data - data.mean(axis=0)
    _, singular, vt = np.linalg.svd(centred, full_matrices=False)
    pca = colour_orders_pca(x)
    assert len(pca.singular) == 24  # 5N − 1
    np.testing.assert_allclose(pca.singular, singular[:24], rtol=1e-9)
    np.testing.assert_allclose(pca.mean, data.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(pca.components @ pca.components.T, np.eye(24), atol=1e-10)
    # Same subspaces wherever k does not split a pair of equal singular values.
    for k in range(1, 25):
        if k < 24 and np.isclose(singular[k - 1], singular[k], rtol=1e-9):
            continue
        np.testing.assert_allclose(_projector(pca.components[:k]), _projector(vt[:k]), atol=1e-8)
    # Each component's singular value is the spread of the permuted data along it.
    np.testing.assert_allclose(np.linalg.norm(centred @ pca.components.T, axis=0), pca.singular, rtol=1e-9)


def test_grey_materials_have_no_chroma_and_their_extra_components_are_unused_directions() -> None:
    rng = np.random.default_rng(4)
    grey = np.repeat(rng.random((4, 1, 30)), 3, axis=1)
    pca = colour_orders_pca(grey)
    assert np.count_nonzero(pca.singular > 1e-9) == 3  # N − 1 grey components only
    np.testing.assert_allclose(pca.components @ pca.components.T, np.eye(len(pca.components)), atol=1e-10)
    with pytest.raises(ValueError, match="count must be in"):
        colour_orders_pca(grey, 20)
    with pytest.raises(ValueError, match=r"shape \(N, 3, P\)"):
        colour_orders_pca(grey[:, :2])


@pytest.mark.slow
def test_the_report_baseline_equals_pca_of_the_permuted_inputs() -> None:
    rng = np.random.default_rng(5)
    inputs = rng.random((3, 63, 90, 90)).astype(np.float32)
    fast = fit_pca_colour_orders(inputs, 14)
    slow = fit_pca(with_colour_permutations(inputs), 14)
    held = rng.random((2, 63, 90, 90)).astype(np.float32)
    np.testing.assert_allclose(fast.decode(fast.encode(held)), slow.decode(slow.encode(held)), atol=2e-4)
    np.testing.assert_allclose(fast.scale, slow.scale, rtol=1e-4)
    with pytest.raises(ValueError, match="n_components"):
        fit_pca_colour_orders(inputs, 15)
