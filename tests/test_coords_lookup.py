"""Rusinkiewicz coordinates, MERL bins and table lookup."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from brdfcodec.conventions import TABLE_SHAPE
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.representation.coords import (
    directions_from_half_diff,
    fold_phi_d,
    grid_angles,
    grid_direction_cosines,
    half_diff_from_directions,
    phi_d_from_index,
    phi_d_index,
    theta_d_from_index,
    theta_d_index,
    theta_h_from_index,
    theta_h_index,
)
from brdfcodec.representation.lookup import lookup
from brdfcodec.representation.mask import horizon_mask


def unit(theta: float, phi: float) -> np.ndarray:
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def test_specular_direction_gives_theta_h_zero() -> None:
    rng = np.random.default_rng(0)
    theta = rng.uniform(0, np.pi / 2 - 1e-3, 500)
    phi = rng.uniform(-np.pi, np.pi, 500)
    wi = np.stack([unit(t, p) for t, p in zip(theta, phi, strict=False)])
    wo = wi * np.array([-1, -1, 1])  # mirror about the normal
    theta_h, theta_d, _, _ = half_diff_from_directions(wi, wo)
    np.testing.assert_allclose(theta_h, 0.0, atol=1e-7)
    np.testing.assert_allclose(theta_d, theta, atol=1e-7)
    assert (theta_h_index(theta_h) == 0).all()


def test_normal_incidence_and_retro_reflection() -> None:
    n = np.array([0.0, 0.0, 1.0])
    th, td, _, _ = half_diff_from_directions(n, n)
    assert th == pytest.approx(0) and td == pytest.approx(0)
    w = unit(0.7, 0.3)
    th, td, _, _ = half_diff_from_directions(w, w)  # retro-reflection: θd = 0, θh = θ
    assert th == pytest.approx(0.7) and td == pytest.approx(0, abs=1e-7)


directions = st.tuples(st.floats(0.01, np.pi / 2 - 0.01), st.floats(-np.pi, np.pi))


@settings(max_examples=200, deadline=None)
@given(directions, directions)
def test_swapping_directions_adds_pi_to_phi_d_and_keeps_bins(a: tuple[float, float], b: tuple[float, float]) -> None:
    wi, wo = unit(*a), unit(*b)
    th1, td1, pd1, _ = half_diff_from_directions(wi, wo)
    th2, td2, pd2, _ = half_diff_from_directions(wo, wi)
    assert th1 == pytest.approx(th2, abs=1e-9) and td1 == pytest.approx(td2, abs=1e-9)
    if td1 < 1e-6:  # ωi ≈ ωo: θd = 0, where φd is undefined (any value describes the same pair)
        return
    folded = abs(fold_phi_d(pd1) - fold_phi_d(pd2))
    assert min(folded, np.pi - folded) < 1e-7


@settings(max_examples=200, deadline=None)
@given(directions, directions)
def test_angles_to_directions_round_trip(a: tuple[float, float], b: tuple[float, float]) -> None:
    wi, wo = unit(*a), unit(*b)
    th, td, pd, ph = half_diff_from_directions(wi, wo)
    wi2, wo2 = directions_from_half_diff(th, td, pd, ph)
    np.testing.assert_allclose(wi2, wi, atol=1e-9)
    np.testing.assert_allclose(wo2, wo, atol=1e-9)


def test_representative_angles_map_to_their_own_bin() -> None:
    i = np.arange(90)
    assert (theta_h_index(theta_h_from_index(i)) == i).all()
    assert (theta_d_index(theta_d_from_index(i)) == i).all()
    k = np.arange(180)
    assert (phi_d_index(phi_d_from_index(k)) == k).all()


def test_bin_edges_and_clamping() -> None:
    assert theta_h_index(np.pi / 2) == 89 and theta_h_index(-0.1) == 0
    assert theta_d_index(np.pi / 2 + 0.3) == 89
    # θh bins are non-linear: bin 1 starts at (1/90)² · 90° ≈ 0.011°
    assert theta_h_index(np.radians(0.01)) == 0 and theta_h_index(np.radians(0.012)) == 1
    # φd folds by reciprocity
    assert phi_d_index(np.pi + phi_d_from_index(7)) == 7
    assert phi_d_index(-np.pi + phi_d_from_index(33)) == 33
    assert phi_d_index(np.pi - 1e-15) == 0  # π ≡ 0


def test_grid_angles_shape_and_subset() -> None:
    th, td, pd = grid_angles()
    assert th.shape == td.shape == pd.shape == (90, 90, 180)
    _, _, pd_sub = grid_angles([0, 9, 179])
    np.testing.assert_allclose(pd_sub[0, 0], phi_d_from_index([0, 9, 179]))


@pytest.mark.parametrize("slices", [None, [0, 9, 90, 179]])
def test_grid_direction_cosines_equal_the_directions_z(slices: list[int] | None) -> None:
    # Bit-identical: the horizon mask (a spec convention) is computed from them.
    wi, wo = directions_from_half_diff(*grid_angles(slices))
    cos_in, cos_out = grid_direction_cosines(slices)
    assert cos_in.shape == cos_out.shape == wi.shape[:-1]
    np.testing.assert_array_equal(cos_in, wi[..., 2])
    np.testing.assert_array_equal(cos_out, wo[..., 2])
    assert (cos_in[:, :, 0] > 0).sum() < cos_in[:, :, 0].size  # some entries are below the horizon


# --- lookup ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def indexed_table() -> np.ndarray:
    """A table whose entry encodes its own bin, to see exactly which bin a lookup hits."""
    c, th, td, pd = np.meshgrid(*(np.arange(n) for n in TABLE_SHAPE), indexing="ij")
    return (c * 1e7 + th * 1e5 + td * 1e3 + pd).astype(np.float64)


@pytest.mark.parametrize("mode", ["nearest", "trilinear"])
def test_lookup_at_representative_angles_returns_that_bin(indexed_table: np.ndarray, mode: str) -> None:
    rng = np.random.default_rng(1)
    # θh = 0 leaves φh, and θd = 0 leaves φd, undefined: every φd bin there is the same configuration.
    valid = np.argwhere(horizon_mask()[1:, 1:]) + [1, 1, 0]
    picks = valid[rng.choice(len(valid), 2000, replace=False)]
    th, td, pd = theta_h_from_index(picks[:, 0]), theta_d_from_index(picks[:, 1]), phi_d_from_index(picks[:, 2])
    wi, wo = directions_from_half_diff(th, td, pd, rng.uniform(-np.pi, np.pi, len(picks)))
    values = lookup(indexed_table, wi, wo, mode=mode)  # type: ignore[arg-type]
    expected = indexed_table[:, picks[:, 0], picks[:, 1], picks[:, 2]].T
    np.testing.assert_allclose(values, expected, rtol=1e-9, atol=1e-6)


@pytest.mark.parametrize("mode", ["nearest", "trilinear"])
def test_lookup_is_reciprocal(analytic_tables: dict[str, MerlBRDF], mode: str) -> None:
    brdf = analytic_tables["red-plastic"]
    rng = np.random.default_rng(2)
    wi = np.stack([unit(t, p) for t, p in zip(rng.uniform(0, 1.5, 300), rng.uniform(-3, 3, 300), strict=False)])
    wo = np.stack([unit(t, p) for t, p in zip(rng.uniform(0, 1.5, 300), rng.uniform(-3, 3, 300), strict=False)])
    a = brdf.eval(wi, wo, mode=mode)  # type: ignore[arg-type]
    b = brdf.eval(wo, wi, mode=mode)  # type: ignore[arg-type]
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-12)


def test_trilinear_is_close_to_the_analytic_brdf(analytic_tables: dict[str, MerlBRDF]) -> None:
    """Off-grid lookups of a smooth material approximate the analytic function it was made from."""
    from brdfcodec.datasets.analytic import ANALYTIC_PRESETS

    material = ANALYTIC_PRESETS["blue-rubber"]
    rng = np.random.default_rng(3)
    wi = np.stack([unit(t, p) for t, p in zip(rng.uniform(0, 1.3, 500), rng.uniform(-3, 3, 500), strict=False)])
    wo = np.stack([unit(t, p) for t, p in zip(rng.uniform(0, 1.3, 500), rng.uniform(-3, 3, 500), strict=False)])
    exact = material.evaluate(wi, wo)
    trilinear = analytic_tables["blue-rubber"].eval(wi, wo, mode="trilinear")
    nearest = analytic_tables["blue-rubber"].eval(wi, wo, mode="nearest")
    err_tri = np.abs(trilinear - exact).mean() / exact.mean()
    err_near = np.abs(nearest - exact).mean() / exact.mean()
    assert err_tri < 0.01
    assert err_tri < err_near


def test_lookup_below_horizon_is_zero(analytic_tables: dict[str, MerlBRDF]) -> None:
    brdf = analytic_tables["white-matte"]
    wi = np.array([[0.0, 0.6, -0.8], [0.0, 0.0, 1.0]])
    wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, -0.8]])
    assert (brdf.eval(wi, wo) == 0).all()
    assert brdf.eval(np.array([0, 0, 1.0]), np.array([0, 0, 1.0]))[0] == pytest.approx(0.8 / np.pi, rel=1e-6)


def test_trilinear_skips_invalid_neighbours() -> None:
    table = np.ones(TABLE_SHAPE)
    mask = np.ones(TABLE_SHAPE, dtype=bool)
    table[:, 10, 10, :] = 1e9  # garbage in invalid entries must not leak
    mask[:, 10, 10, :] = False
    wi, wo = directions_from_half_diff(theta_h_from_index(10.5), theta_d_from_index(10.5), 0.3)
    assert lookup(table, wi, wo, mode="trilinear", mask=mask) == pytest.approx([1.0, 1.0, 1.0])
    assert (lookup(table, *directions_from_half_diff(theta_h_from_index(10), theta_d_from_index(10), 0.3),
                   mask=mask) == 0).all()


def test_lookup_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="shape"):
        lookup(np.zeros((3, 90, 90)), [0, 0, 1], [0, 0, 1])
    with pytest.raises(ValueError, match="mode"):
        lookup(np.zeros(TABLE_SHAPE), [0, 0, 1], [0, 0, 1], mode="cubic")  # type: ignore[arg-type]
