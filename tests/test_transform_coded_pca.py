"""The strong PCA baselines of issue 48 (brdfcodec.report.pca_coding): transform-coded and entropy-coded."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfcodec.layers.bit_allocation import allocate_bits
from brdfcodec.report.pca_coding import EntropyCodedPca, TransformCodedPca, coded_pca_rows, gaussian_loading

SPREADS = 10.0 * np.exp(-np.arange(120) / 15.0)


def _materials(count: int = 24, seed: int = 0, laplace: bool = False) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if laplace:
        return rng.laplace(0, SPREADS / math.sqrt(2), (count, len(SPREADS)))
    return rng.normal(0, SPREADS, (count, len(SPREADS)))


def _int8_error(c: np.ndarray, budget: int) -> float:
    """The int8 + float16-scale packing of the first N − 2 coefficients (the earlier baseline)."""
    k = budget - 2
    scale = np.float32(np.float16(max(float(np.abs(c[:k]).max()), 1e-6) / 127.0))
    decoded = np.zeros_like(c)
    decoded[:k] = np.clip(np.rint(c[:k] / scale), -127, 127) * scale
    return float(np.sum((decoded - c) ** 2))


def test_gaussian_loading_is_the_known_optimum() -> None:
    # Max (1960) / Jayant & Noll: optimal uniform quantisers of a unit Gaussian, 2, 4 and 8 levels.
    assert [round(gaussian_loading(b), 3) for b in (1, 2, 3)] == [1.596, 1.991, 2.344]
    assert all(gaussian_loading(b + 1) > gaussian_loading(b) for b in range(1, 14))


@pytest.mark.parametrize("budget", [16, 32, 64, 128])
def test_transform_coding_fills_the_budget_with_water_filled_bits(budget: int) -> None:
    coder = TransformCodedPca(SPREADS, budget)
    assert coder.bits.tolist() == allocate_bits(SPREADS**2, 8 * (budget - 1), max_bits=16).tolist()
    assert coder.payload_bytes == budget
    for c in _materials(4):
        payload = coder.encode(c)
        assert len(payload) == budget
        decoded = coder.decode(payload)
        assert np.all(decoded[coder.bits == 0] == 0)
        assert coder.encode(decoded) == payload  # the decode is a fixed point: the bytes hold the values


def test_transform_coding_beats_int8_coefficients_and_improves_with_the_budget() -> None:
    materials = _materials()
    previous = math.inf
    for budget in (16, 32, 64, 128):
        coder = TransformCodedPca(SPREADS, budget)
        error = np.mean([np.sum((coder.decode(coder.encode(c)) - c) ** 2) for c in materials])
        assert error < np.mean([_int8_error(c, budget) for c in materials])
        assert error < previous
        previous = error


def test_the_gain_byte_follows_a_material_beyond_the_training_spread() -> None:
    coder = TransformCodedPca(SPREADS, 32)
    c = 4.0 * _materials(1)[0]
    payload = coder.encode(c)
    assert payload[0] > 128  # a gain above 1
    forced = bytes([128]) + coder.encode(c * 0.25)[1:]  # unit gain: the training spread's clip range
    error = np.sum((coder.decode(payload) - c) ** 2)
    assert error < np.sum((coder.decode(forced) - c) ** 2)


def test_entropy_coding_stays_within_the_budget_at_the_finest_step_that_fits() -> None:
    for budget in (16, 64):
        coder = EntropyCodedPca(SPREADS, budget)
        for c in _materials(6, seed=1, laplace=True):
            payload = coder.encode(c)
            assert len(payload) <= budget
            step = coder.step(payload[0])
            assert np.allclose(coder.decode(payload), np.rint(c / step) * step)
            if payload[0] < coder.finest_code:  # one code finer no longer fits
                assert len(coder._code(c, payload[0] + 1)) > budget


def test_a_material_far_outside_the_training_spread_keeps_the_leading_coefficients_that_fit() -> None:
    """A held-out material whose trailing coefficients are far beyond their training spread: the coarsest step
    does not fit the budget (the bench run of a fold stopped with "no step fits 32 bytes"); the leading
    coefficients that fit are coded, the rest as 0, within the budget."""
    coder = EntropyCodedPca(SPREADS, 16)
    c = np.where(np.arange(len(SPREADS)) < 10, SPREADS, 1e3 * SPREADS.max())
    assert len(coder._code(c, 0)) > 16  # the case: even the coarsest step overflows
    payload = coder.encode(c)
    assert len(payload) <= 16 and payload[0] == 0
    decoded = coder.decode(payload)
    kept = int(np.flatnonzero(decoded)[-1]) + 1 if np.any(decoded) else 0
    assert kept >= 1 and np.all(decoded[kept:] == 0)
    assert np.allclose(decoded[:kept], np.clip(np.rint(c[:kept] / coder.step(0)), -coder._bounds(coder.step(0))[:kept],
                                               coder._bounds(coder.step(0))[:kept]) * coder.step(0))


def test_entropy_coding_beats_fixed_rate_coding_on_laplacian_coefficients() -> None:
    materials = _materials(laplace=True, seed=2)
    for budget in (32, 128):
        tc, ec = TransformCodedPca(SPREADS, budget), EntropyCodedPca(SPREADS, budget)
        tc_error = np.mean([np.sum((tc.decode(tc.encode(c)) - c) ** 2) for c in materials])
        ec_error = np.mean([np.sum((ec.decode(ec.encode(c)) - c) ** 2) for c in materials])
        assert ec_error < tc_error


@pytest.mark.parametrize("make", [
    lambda: TransformCodedPca([1.0, 0.0], 16),
    lambda: TransformCodedPca([1.0], 0),
    lambda: EntropyCodedPca([1.0], 1),
    lambda: EntropyCodedPca([1.0], 16, "cauchy"),  # type: ignore[arg-type]
])
def test_bad_configurations_are_refused(make) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError):
        make()


def test_bad_coefficients_and_payloads_are_refused() -> None:
    coder = TransformCodedPca(SPREADS, 16)
    with pytest.raises(ValueError):
        coder.encode(np.full(len(SPREADS), np.nan))
    with pytest.raises(ValueError):
        coder.decode(b"\0" * 15)
    with pytest.raises(ValueError):
        EntropyCodedPca(SPREADS, 16).decode(b"")


def test_rows_score_what_the_decoder_reads_back() -> None:
    from brdfcodec.models.pca import fit_pca

    rng = np.random.default_rng(3)
    inputs = rng.random((7, 63, 90, 90)).astype(np.float32) * 0.1
    basis = fit_pca(inputs[:5], 4)
    seen: list[np.ndarray] = []

    def error(reference: object, table: np.ndarray) -> tuple[float, float]:
        seen.append(table)
        return float(reference), 0.5  # type: ignore[arg-type]

    rows = coded_pca_rows("pca", basis, inputs[5:], [0.1, 0.3], [16, 32], error)
    assert {(row["point"], row["budget_bytes"]) for row in rows} == {
        (f"pca-{kind}", n) for kind in ("tc", "ec-laplace", "ec-gaussian") for n in (16, 32)}
    for row in rows:
        assert row["bytes_max"] <= row["budget_bytes"] and row["per_material_mapped"] == [0.1, 0.3]
        assert row["mapped_relae_mean"] == pytest.approx(0.2) and row["linear_relae_mean"] == 0.5
    assert len(seen) == 12 and all(np.all(np.isfinite(t)) for t in seen)


def test_the_summary_takes_the_best_of_every_pca_variant_and_shows_the_int8_one() -> None:
    from brdfcodec.report.rows import summary_markdown

    def row(point: str, errors: list[float], size: float) -> dict:  # type: ignore[type-arg]
        return {"schema": "brdfcodec.rows/1", "group": "g", "family": "merl", "point": point, "budget_bytes": 32,
                "bytes_per_material": size, "per_material_mapped": errors}

    rows = [row("bvae", [0.03], 31.5), row("pca-perm-int8", [0.04], 32), row("pca-perm-float16", [0.05], 32),
            row("pca-perm-tc", [0.028], 32), row("pca-perm-ec-laplace", [0.025], 31.2)]
    table = summary_markdown(rows)
    assert "| 32 B | 0.0300 | 31.5 | 0.0250 | pca-perm-ec-laplace | 31 | 0.0400 | no |" in table, table
