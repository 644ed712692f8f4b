"""Reverse water-filling (brdfcodec.layers.bit_allocation): closed forms, integer optimality, nesting."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from brdfcodec.layers.bit_allocation import allocate_bits, predicted_distortion, reverse_water_filling


def test_two_active_coefficients_match_the_closed_form() -> None:
    # Both active: θ = σ₁σ₂·2^(−R), bᵢ = ½log₂(σᵢ²/θ).
    v1, v2, budget = 9.0, 4.0, 3.0
    solution = reverse_water_filling([v2, v1], budget)
    level = math.sqrt(v1 * v2) * 2.0**-budget
    assert solution.level == pytest.approx(level)
    assert solution.bits == pytest.approx([0.5 * math.log2(v2 / level), 0.5 * math.log2(v1 / level)])
    assert solution.distortion == pytest.approx(2 * level)


def test_a_small_variance_below_the_level_gets_no_bit() -> None:
    # With R = ½ bit only the largest variance is active: θ = 4·2^(−1) = 2 > 1 > 0.25.
    solution = reverse_water_filling([1.0, 4.0, 0.25], 0.5)
    assert solution.bits == pytest.approx([0.0, 0.5, 0.0])
    assert solution.level == pytest.approx(2.0)
    assert solution.distortion == pytest.approx(2.0 + 1.0 + 0.25)


def test_bits_sum_to_the_budget_and_distortion_is_the_model_of_the_bits() -> None:
    rng = np.random.default_rng(0)
    variances = np.exp(rng.normal(0, 3, 60))
    for budget in (0.0, 0.3, 5.0, 47.5, 400.0):
        solution = reverse_water_filling(variances, budget)
        assert solution.bits.sum() == pytest.approx(budget, abs=1e-9)
        assert np.all(solution.bits >= 0)
        assert solution.distortion == pytest.approx(predicted_distortion(variances, solution.bits), rel=1e-9)


def test_distortion_falls_with_the_budget() -> None:
    variances = [5.0, 3.0, 1.0, 0.1, 0.0]
    values = [reverse_water_filling(variances, r).distortion for r in np.linspace(0, 20, 41)]
    assert all(b < a for a, b in itertools.pairwise(values))


def test_whole_bits_are_optimal_under_the_model() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        variances = np.exp(rng.normal(0, 2, 3))
        budget = int(rng.integers(0, 9))
        best = min(predicted_distortion(variances, b) for b in itertools.product(range(budget + 1), repeat=3)
                   if sum(b) == budget)
        assert predicted_distortion(variances, allocate_bits(variances, budget)) == pytest.approx(best)


def test_whole_bits_are_nested_in_the_budget() -> None:
    rng = np.random.default_rng(2)
    variances = np.exp(rng.normal(0, 3, 40))
    variances[5] = 0.0
    previous = allocate_bits(variances, 0)
    assert previous.sum() == 0
    for budget in range(1, 700):
        bits = allocate_bits(variances, budget, max_bits=16)
        assert np.all(bits >= previous)
        assert bits.sum() == min(budget, 16 * 39)
        assert bits[5] == 0 and bits.max() <= 16
        previous = bits


def test_whole_bits_stay_within_a_bit_of_the_continuous_solution() -> None:
    rng = np.random.default_rng(3)
    variances = np.exp(rng.normal(0, 2, 30))
    for budget in (10, 64, 200):
        continuous = reverse_water_filling(variances, budget).bits
        assert np.all(np.abs(allocate_bits(variances, budget, max_bits=62) - continuous) <= 1.0 + 1e-9)


@pytest.mark.parametrize("call", [
    lambda: reverse_water_filling([1.0, -1.0], 2),
    lambda: reverse_water_filling([1.0, np.nan], 2),
    lambda: reverse_water_filling([[1.0]], 2),
    lambda: reverse_water_filling([1.0], -1),
    lambda: reverse_water_filling([1.0], np.inf),
    lambda: allocate_bits([1.0], 2.5),
    lambda: allocate_bits([1.0], -1),
    lambda: allocate_bits([1.0], 4, max_bits=0),
    lambda: predicted_distortion([1.0, 2.0], [1.0]),
    lambda: predicted_distortion([1.0], [-1.0]),
])
def test_bad_input_is_refused(call) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError):
        call()
