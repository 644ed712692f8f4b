"""The data spine (brdfcodec.representation): each conversion against its definition and its inverse."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.conventions import MAPPED_MAX, MERL_COLOR_SCALE, NETWORK_INPUT_SHAPE
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.representation import (
    clamp_mapped,
    from_network_layout,
    interpolate_slices,
    map_values,
    network_channels_for_slots,
    network_input_from_table,
    reflectance_from_mapped,
    reflectance_from_stored,
    select_kept_slices,
    stored_from_reflectance,
    table_from_mapped,
    table_from_network_output,
    to_network_layout,
    unmap_values,
    validate_phi_d_bins,
)


def test_units_are_the_colour_scale_and_its_inverse() -> None:
    stored = np.random.default_rng(0).uniform(0, 1e4, (3, 4, 5))
    reflectance = reflectance_from_stored(stored)
    np.testing.assert_array_equal(reflectance, stored * MERL_COLOR_SCALE[:, None, None])
    np.testing.assert_allclose(stored_from_reflectance(reflectance), stored, rtol=1e-15)
    moved = reflectance_from_stored(np.moveaxis(stored, 0, -1), channel_axis=-1)
    np.testing.assert_array_equal(np.moveaxis(moved, -1, 0), reflectance)
    assert reflectance_from_stored(stored.astype(np.float32)).dtype == np.float32
    with pytest.raises(ValueError, match="3 channels"):
        reflectance_from_stored(np.ones((4, 2)))


def test_clamp_is_the_mapped_domain_with_nan_as_zero() -> None:
    raw = np.array([-3.0, np.nan, 0.5, MAPPED_MAX + 1, np.inf, -np.inf], dtype=np.float32)
    np.testing.assert_array_equal(clamp_mapped(raw), [0.0, 0.0, 0.5, MAPPED_MAX, MAPPED_MAX, 0.0])
    in_place = raw.copy()
    assert clamp_mapped(in_place, out=in_place) is in_place
    np.testing.assert_array_equal(in_place, [0.0, 0.0, 0.5, MAPPED_MAX, MAPPED_MAX, 0.0])
    assert clamp_mapped(np.array(np.nan)) == 0.0 and clamp_mapped(np.float64(9.0)) == MAPPED_MAX  # 0-d
    lone_nan = np.full((63, 90, 90), 0.25, dtype=np.float32)
    lone_nan[40, 89, 89] = np.nan  # one NaN among many values is still found
    assert clamp_mapped(lone_nan)[40, 89, 89] == 0.0 and clamp_mapped(lone_nan).dtype == np.float32


def test_network_input_is_the_mapped_kept_slices_with_invalid_entries_zero(
    analytic_tables: dict[str, MerlBRDF],
) -> None:
    brdf = analytic_tables["gold"]
    inputs, mask = network_input_from_table(brdf.values)
    assert inputs.shape == mask.shape == NETWORK_INPUT_SHAPE and inputs.dtype == np.float32
    expected = np.where(select_kept_slices(brdf.mask), select_kept_slices(map_values(brdf.values)), 0.0)
    np.testing.assert_allclose(from_network_layout(inputs), expected, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(from_network_layout(mask), select_kept_slices(brdf.mask))
    assert (inputs[~mask] == 0).all()
    np.testing.assert_array_equal(to_network_layout(from_network_layout(inputs)), inputs)


def test_tables_from_network_output_clamp_once_then_interpolate_and_unmap() -> None:
    rng = np.random.default_rng(1)
    raw = rng.normal(1.0, 2.5, NETWORK_INPUT_SHAPE).astype(np.float32)  # a third out of the domain
    raw[0, 0, :3] = np.nan
    clamped = clamp_mapped(raw)
    table = table_from_network_output(raw)
    np.testing.assert_array_equal(table, table_from_mapped(clamped))
    reference = unmap_values(interpolate_slices(from_network_layout(clamped.astype(np.float64))))
    np.testing.assert_allclose(table, reference, rtol=2e-5)
    assert np.isfinite(table).all() and (table >= 0).all()
    bins = [0, 5, 179]
    np.testing.assert_allclose(table_from_mapped(clamped, phi_d_bins=bins), table[..., bins], rtol=1e-5)  # BLAS order
    np.testing.assert_allclose(reflectance_from_mapped(clamped), reflectance_from_stored(table), rtol=1e-6)


def test_bins_and_channels_are_checked_once_in_one_place() -> None:
    assert validate_phi_d_bins([3, 1]) == (3, 1)
    for bad in ([], [180], [-1]):
        with pytest.raises(ValueError, match="phi_d_bins"):
            validate_phi_d_bins(bad)
        with pytest.raises(ValueError, match="phi_d_bins"):
            table_from_mapped(np.zeros(NETWORK_INPUT_SHAPE, np.float32), phi_d_bins=bad)
    assert network_channels_for_slots([0, 20], colours=(1, 2)) == [21, 41, 42, 62]
