"""The encoder's fits on a factorised basis' factors (:mod:`brdfcodec.codec.basis_operator`, issue 48): the same
sums and dot products as the dense vectors, the same fitted coefficients, and the dense vectors never built."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from brdfcodec.codec.basis_operator import BasisOperator
from brdfcodec.codec.refine import fit_basis_only_coefficients, polish_quantised_coefficients
from brdfcodec.layers.basis import SharedBasis, extend_factorised_basis, fit_factorised_basis


def _basis() -> SharedBasis:
    """A factorised basis of 20 vectors (6 in binary16, 14 in 8 bits) over 3 × 8,200 entries."""
    rng = np.random.default_rng(5)
    width = 8200
    values = rng.normal(size=(9, 3 * width)) @ np.diag(np.linspace(3.0, 0.1, 3 * width))
    masks = np.ones_like(values, dtype=bool)
    grown = extend_factorised_basis(fit_factorised_basis(values, masks, 6), fit_factorised_basis(values, masks, 20))
    assert grown.factors_int8 is not None
    return SharedBasis(None, grown.entries(), "ab" * 32, grown)


@pytest.mark.parametrize(("first", "k"), [(0, 20), (0, 1), (4, 9), (6, 14), (19, 1)])
def test_sums_and_dot_products_on_the_factors_are_the_dense_vectors(first: int, k: int) -> None:
    basis = _basis()
    dense = basis.factorised.products(first, k).astype(np.float64)
    operator = BasisOperator.of(basis, first, k)
    rng = np.random.default_rng(first * 31 + k)
    c = rng.normal(size=(3, k)).astype(np.float32)
    r = rng.normal(size=(2, dense.shape[1])).astype(np.float32)
    scale_c, scale_r = np.abs(c @ dense).max(), np.abs(r @ dense.T).max()
    assert np.allclose(operator.synthesise(torch.from_numpy(c)).numpy(), c @ dense, atol=1e-5 * scale_c)
    assert np.allclose(operator.analyse(torch.from_numpy(r)).numpy(), r @ dense.T, atol=1e-5 * scale_r)
    assert np.array_equal(operator.row(k - 1), basis.factorised.products(first + k - 1, 1)[0])
    assert np.allclose(operator.combine(c[0]), c[0] @ dense, atol=1e-5 * scale_c)
    assert "_float32" not in basis.__dict__, "the dense vectors were built"


def test_fits_on_the_factors_match_fits_on_the_dense_vectors() -> None:
    basis = _basis()
    rng = np.random.default_rng(9)
    dense = basis.factorised.products(0, 20)
    centre = rng.normal(scale=0.1, size=dense.shape[1]).astype(np.float32) + 1.0
    target = centre + rng.normal(size=20).astype(np.float32) @ dense * 0.05
    weights = (rng.random(dense.shape[1]) > 0.1).astype(np.float32)
    operator = BasisOperator.of(basis, 0, 20)
    on_factors = fit_basis_only_coefficients(target, weights, centre, operator, 1)
    on_dense = fit_basis_only_coefficients(target, weights, centre, dense, 1)
    assert np.allclose(on_factors, on_dense, atol=1e-3 * np.abs(on_dense).max())
    step = float(np.abs(on_dense).max() / 127)
    q = np.rint(on_dense / step).astype(np.int64)
    polished = polish_quantised_coefficients(step, q, target, weights, centre, operator, 2)
    assert np.array_equal(polished, polish_quantised_coefficients(step, q, target, weights, centre, dense, 2))
    assert "_float32" not in basis.__dict__, "the dense vectors were built"


def test_vectors_that_do_not_exist_are_refused() -> None:
    from brdfcodec.errors import BasisError

    with pytest.raises(BasisError, match="holds 20"):
        BasisOperator.of(_basis(), 15, 6)
    with pytest.raises(ValueError, match=r"\(k, E\)"):
        BasisOperator.from_vectors(np.zeros(5))
