"""RelAE (linear and mapped) and cosine-weighted RMSE."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.conventions import MERL_COLOR_SCALE, TABLE_SHAPE
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.representation import interpolate_slices, select_kept_slices
from brdfcodec.representation.mask import horizon_mask
from brdfcodec.representation.metrics import (
    RelaeAgainst,
    cosine_weighted_rmse,
    error_report,
    relae_both,
    relae_linear,
    relae_mapped,
)


def test_identical_tables_have_zero_error(analytic_tables: dict[str, MerlBRDF]) -> None:
    values = analytic_tables["gold"].values
    report = error_report(values, values)
    for metric in report.as_dict().values():
        assert all(v == 0.0 for v in metric.values())


def test_uniform_relative_error(analytic_tables: dict[str, MerlBRDF]) -> None:
    values = analytic_tables["red-plastic"].values
    estimate = np.where(values >= 0, values * 1.1, values)
    linear = relae_linear(values, estimate)
    assert linear.overall == pytest.approx(0.1) and linear.red == pytest.approx(0.1)
    assert linear.green == pytest.approx(0.1) and linear.blue == pytest.approx(0.1)
    # The log mapping compresses a 10 % error into less than 10 %.
    assert 0 < relae_mapped(values, estimate).overall < 0.1


def test_linear_overall_weights_channels_by_physical_magnitude() -> None:
    reference = np.where(horizon_mask()[None], 1.0, -1.0) / MERL_COLOR_SCALE[:, None, None, None]
    reference[0] *= 10  # red ten times brighter than green and blue (physically)
    estimate = reference.copy()
    estimate[1] *= 1.5  # 50 % error on green only
    linear = relae_linear(reference, estimate)
    assert linear.green == pytest.approx(0.5) and linear.red == 0 and linear.blue == 0
    assert linear.overall == pytest.approx(0.5 * 1 / 12)


def test_invalid_entries_are_ignored(analytic_tables: dict[str, MerlBRDF]) -> None:
    values = analytic_tables["blue-rubber"].values
    estimate = values.copy()
    estimate[:, ~horizon_mask()] = 1e12  # garbage below the horizon
    assert relae_linear(values, estimate).overall == 0
    custom = np.zeros(TABLE_SHAPE, dtype=bool)
    custom[:, 0, 0, 0] = True
    est2 = values * 2
    assert relae_mapped(values, est2, custom).overall > 0
    assert cosine_weighted_rmse(values, est2, custom).overall > 0


def test_cosine_weighted_rmse_of_constant_offset() -> None:
    reference = np.where(horizon_mask()[None], 0.0, -1.0) * np.ones(TABLE_SHAPE)
    estimate = np.zeros(TABLE_SHAPE) + 1.0 / MERL_COLOR_SCALE[:, None, None, None]  # +1 /sr everywhere
    rmse = cosine_weighted_rmse(reference, estimate)
    # RMS of cos θi over valid entries: between 0 and 1, equal for all channels.
    assert 0.3 < rmse.overall < 1.0
    assert rmse.red == pytest.approx(rmse.green) == pytest.approx(rmse.blue) == pytest.approx(rmse.overall)


def test_slice_interpolation_error_floor_is_small_for_smooth_materials(analytic_tables: dict[str, MerlBRDF]) -> None:
    values = analytic_tables["blue-rubber"].values
    rebuilt = interpolate_slices(select_kept_slices(np.maximum(values, 0)))
    assert relae_mapped(values, rebuilt).overall < 0.01


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="shape"):
        relae_linear(np.zeros((3, 2)), np.zeros((3, 2)))
    good = np.ones(TABLE_SHAPE)
    with pytest.raises(ValueError, match="NaN"):
        relae_linear(good, np.full(TABLE_SHAPE, np.nan))


def test_zero_reference_gives_nan_not_an_exception() -> None:
    zeros = np.zeros(TABLE_SHAPE)
    assert np.isnan(relae_linear(zeros, zeros).overall)


@pytest.mark.slow
def test_one_reference_against_many_estimates_gives_the_same_numbers(analytic_tables: dict[str, MerlBRDF]) -> None:
    values = analytic_tables["gold"].values
    rng = np.random.default_rng(3)
    mask = horizon_mask()[None] & (rng.random(TABLE_SHAPE) > 0.1)
    reference = np.where(mask, values, np.nan)  # what lies off the mask must not matter
    against = {metric: RelaeAgainst(reference, mask, metric) for metric in ("mapped", "linear")}
    for scale in (0.02, 0.3):
        estimate = np.where(mask, values * (1 + scale * rng.standard_normal(TABLE_SHAPE)), -1.0)
        linear, mapped = relae_both(reference, estimate, mask)
        assert linear == relae_linear(reference, estimate, mask) == against["linear"](estimate)
        assert mapped == relae_mapped(reference, estimate, mask) == against["mapped"](estimate)
        assert mapped.as_dict() == error_report(reference, estimate, mask).relae_mapped.as_dict()
        assert 0 < mapped.overall < linear.overall
    with pytest.raises(ValueError, match="NaN"):
        against["mapped"](np.where(mask, np.inf, 0.0))
    with pytest.raises(ValueError, match="shape"):
        against["linear"](np.zeros((3, 2)))
    with pytest.raises(ValueError, match="metric"):
        RelaeAgainst(values, metric="log")
