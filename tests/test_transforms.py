"""Log mapping, kept slices, network layout and interpolation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from brdfcodec.conventions import (
    EPSILON,
    KEPT_PHI_D_SLICES,
    MAPPED_MAX,
    MERL_COLOR_SCALE,
    NETWORK_INPUT_SHAPE,
    TABLE_SHAPE,
)
from brdfcodec.representation import (
    from_network_layout,
    interpolate_slices,
    map_values,
    select_kept_slices,
    to_network_layout,
    unmap_values,
)
from brdfcodec.representation.mask import horizon_mask, kept_slice_horizon_mask


def paper_mapping(rho: np.ndarray, scale: float) -> np.ndarray:
    """Eq. 1 of the paper as printed (with the corrected green scale)."""
    return (np.log(rho * scale + EPSILON) - np.log(EPSILON)) / (np.log(1 + EPSILON) - np.log(EPSILON))


def test_kept_slices_are_the_specified_ones() -> None:
    assert KEPT_PHI_D_SLICES == (0, 9, 18, 27, 36, 45, 54, 63, 72, 81, 90, 99, 108, 117, 126, 135, 144, 153, 162,
                                 171, 179)
    assert NETWORK_INPUT_SHAPE == (63, 90, 90)


def test_mapping_matches_the_paper_formula() -> None:
    rho = np.geomspace(1e-6, 1e6, 200)
    values = np.stack([rho, rho, rho])
    mapped = map_values(values)
    for c in range(3):
        # log1p is more accurate than the printed log(x + ε) − log(ε) for tiny x.
        np.testing.assert_allclose(mapped[c], paper_mapping(rho, MERL_COLOR_SCALE[c]), rtol=1e-6)
    # A reflectance of exactly 1/sr maps to 1, zero to zero.
    ones = (1.0 / MERL_COLOR_SCALE)[:, None]
    np.testing.assert_allclose(map_values(ones), 1.0, rtol=1e-12)
    assert (map_values(np.zeros((3, 4))) == 0).all()


def test_inverse_is_exact_to_1e6_relative_from_0_to_1e6() -> None:
    # (Subnormal inputs, below 2.2e-308, come back as 0: an absolute error under 1e-307.)
    rho = np.concatenate([[0.0, 1e-300, 1e-12], np.geomspace(1e-9, 1e6, 5000)])
    values = np.stack([rho, rho, rho])
    back = unmap_values(map_values(values))
    np.testing.assert_allclose(back, values, rtol=1e-6, atol=0)
    assert np.isfinite(back).all()


def test_float32_and_float16_paths_stay_finite() -> None:
    rho32 = np.stack([np.geomspace(1e-6, 1e6, 1000).astype(np.float32)] * 3)
    mapped32 = map_values(rho32)
    assert mapped32.dtype == np.float32 and np.isfinite(mapped32).all()
    np.testing.assert_allclose(unmap_values(mapped32), rho32, rtol=1e-5)
    rho16 = np.stack([np.geomspace(1e-3, 6e4, 500).astype(np.float16)] * 3)
    mapped16 = map_values(rho16)
    assert np.isfinite(mapped16).all() and mapped16.dtype == np.float32
    # A float16 network output decodes in float32 (tables exceed float16's range).
    decoded = unmap_values(mapped16.astype(np.float16))
    assert decoded.dtype == np.float32 and np.isfinite(decoded).all()
    np.testing.assert_allclose(decoded, rho16.astype(np.float32), rtol=1e-2)


def test_inverse_clamps_to_the_mapped_domain() -> None:
    wild = np.array([[-1e30, -1.0, np.nan, 0.5, MAPPED_MAX, 1e4, np.inf]] * 3)
    for dtype in (np.float16, np.float32, np.float64):
        with np.errstate(over="ignore"):  # -1e30 is -inf in float16, on purpose
            cast = wild.astype(dtype)
        out = unmap_values(cast)
        assert np.isfinite(out).all() and (out >= 0).all()
        np.testing.assert_allclose(out[:, [0, 1, 2]], 0.0)
        np.testing.assert_allclose(out[:, -1], out[:, 4], rtol=1e-6)
    # The top of the mapped domain is about 1.05e8 /sr physical in every channel.
    top = unmap_values(np.full((3, 1), MAPPED_MAX)) * MERL_COLOR_SCALE[:, None]
    np.testing.assert_allclose(top, EPSILON * (101.0**MAPPED_MAX - 1), rtol=1e-9)


def test_negative_unmeasured_values_map_to_zero() -> None:
    assert (map_values(np.full((3, 2), -1.0)) == 0).all()


def test_channel_axis_argument() -> None:
    values = np.random.default_rng(0).lognormal(0, 2, (5, 3))
    np.testing.assert_allclose(map_values(values, channel_axis=1), map_values(values.T).T)
    with pytest.raises(ValueError, match="3 channels"):
        map_values(np.ones((4, 5)))


def test_network_layout_round_trip_and_order() -> None:
    rng = np.random.default_rng(1)
    kept = rng.random((3, 90, 90, 21)).astype(np.float32)
    net = to_network_layout(kept)
    assert net.shape == (63, 90, 90)
    # Channel k is colour k // 21 at kept slice k % 21.
    np.testing.assert_array_equal(net[21 * 2 + 5], kept[2, :, :, 5])
    np.testing.assert_array_equal(from_network_layout(net), kept)
    batch = np.stack([kept, kept * 2])
    np.testing.assert_array_equal(from_network_layout(to_network_layout(batch)), batch)


def test_interpolation_returns_kept_slices_exactly_and_is_linear_between() -> None:
    rng = np.random.default_rng(2)
    table = rng.lognormal(0, 3, TABLE_SHAPE)
    kept = select_kept_slices(table)
    full = interpolate_slices(kept)
    assert full.shape == TABLE_SHAPE and full.dtype == np.float64
    for slot, p in enumerate(KEPT_PHI_D_SLICES):
        np.testing.assert_array_equal(full[..., p], kept[..., slot])
    np.testing.assert_allclose(full[..., 4], kept[..., 0] * 5 / 9 + kept[..., 1] * 4 / 9)
    np.testing.assert_allclose(full[..., 175], kept[..., 19] * 4 / 8 + kept[..., 20] * 4 / 8)


def test_interpolation_reproduces_functions_linear_in_phi_d() -> None:
    phi = np.arange(180, dtype=np.float64)
    line = np.broadcast_to(3.0 * phi - 7.0, (2, 180))
    np.testing.assert_allclose(interpolate_slices(select_kept_slices(line)), line, rtol=1e-12)


def test_interpolation_keeps_dtype_and_finiteness() -> None:
    for dtype in (np.float16, np.float32):
        kept = np.full((3, 21), 6e4, dtype=dtype)
        full = interpolate_slices(kept)
        assert full.dtype == dtype and np.isfinite(full).all()


def test_shape_errors() -> None:
    with pytest.raises(ValueError, match="180"):
        select_kept_slices(np.zeros((3, 20)))
    with pytest.raises(ValueError, match="21"):
        interpolate_slices(np.zeros((3, 20)))
    with pytest.raises(ValueError, match="network layout"):
        from_network_layout(np.zeros((62, 90, 90)))


def test_horizon_mask_counts() -> None:
    mask = horizon_mask()
    assert mask.shape == (90, 90, 180) and not mask.flags.writeable
    assert mask[:, 0, :].all()  # θd = 0: both directions at θh < 90°
    assert not mask[89, 89, 0]  # grazing in the plane of incidence
    assert kept_slice_horizon_mask().shape == (90, 90, 21)
    np.testing.assert_array_equal(kept_slice_horizon_mask(), mask[:, :, list(KEPT_PHI_D_SLICES)])


@settings(max_examples=300, deadline=None)
@given(
    hnp.arrays(np.float64, st.tuples(st.just(3), st.integers(1, 6)),
               elements=st.floats(0.0, 1e6, allow_nan=False, allow_infinity=False)),
)
def test_round_trip_property(values: np.ndarray) -> None:
    back = unmap_values(map_values(values))
    tiny = values < 1e-300  # subnormals and zero
    np.testing.assert_allclose(back[~tiny], values[~tiny], rtol=1e-6)
    assert (back[tiny] <= 1e-300).all()


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.float32, (3, 4), elements=st.floats(width=32)))
def test_unmap_is_finite_and_non_negative_for_any_float32(mapped: np.ndarray) -> None:
    out = unmap_values(mapped)
    assert np.isfinite(out).all() and (out >= 0).all()
