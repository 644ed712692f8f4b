"""Rate control as one rate–distortion choice (issue 48, 2): the lowest distortion among the candidates that fit a
budget, the basis codings compared per material, and the Lagrangian hull of the candidates."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.codec.rate import encode_layers, lagrangian_hull, lowest_distortion
from brdfcodec.conventions import NETWORK_INPUT_SHAPE
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.layers.basis import quantise_coefficients

_SHA = "cd" * 32


def test_the_hull_keeps_the_points_a_lagrangian_sweep_reaches() -> None:
    # (rate, distortion): (20, 6) lies above the chord of (10, 8) and (40, 2); (30, 9) is beaten by a smaller point
    points = [(10.0, 8.0), (20.0, 6.0), (30.0, 9.0), (40.0, 2.0), (5.0, 12.0)]
    hull = lagrangian_hull(points)
    assert [i for i, _, _ in hull] == [4, 0, 3]
    (_, low5, high5), (_, low10, high10), (_, low40, high40) = hull
    assert high5 == np.inf and low5 == high10 == pytest.approx(4 / 5) and low10 == high40 == pytest.approx(0.2)
    assert low40 == 0.0
    for lam in (0.1, 0.5, 2.0):  # each λ's minimiser of D + λR is the hull point whose range holds λ
        best = min(range(len(points)), key=lambda i: points[i][1] + lam * points[i][0])
        assert any(i == best and low <= lam <= high for i, low, high in hull)


def _case():
    target = np.full(NETWORK_INPUT_SHAPE, 0.5, dtype=np.float32)
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", np.linspace(-1, 1, 8), np.ones(8))
    return base, target, masks


@pytest.mark.parametrize("better", ["packed", "coded"])
def test_a_budget_keeps_the_basis_coding_of_lower_error(better: str) -> None:
    base, target, masks = _case()
    asked: list[tuple[int, str | None]] = []

    def fit(k: int, mu_storage: str | None, under_detail: bool, coding: str | None = None):  # noqa: ANN202, ARG001
        asked.append((k, coding))
        share = 0.99 if coding == better else 0.9
        return base, quantise_coefficients(_SHA, np.ones(k)), (target * share).astype(np.float32)

    result = encode_layers(base, target * 0.5, target, masks, bytes_budget=40, basis_fit=fit, basis_count=75,
                           basis_variants=("packed", "coded"))
    assert {coding for _, coding in asked} == {"packed", "coded"}
    chosen = next(p for p in result.points if p.rate == result.payload_bytes and p.option[2] == better)
    assert chosen.distortion == min(p.distortion for p in result.points)
    assert result.payload_bytes <= 40 and result.record.basis is not None
    # the record is the better coding's: its error is the lowest of the candidates measured
    errors = {p.option[2]: p.distortion for p in result.points if p.option[0]}
    assert errors[better] < errors["coded" if better == "packed" else "packed"]


def test_on_a_tie_the_coding_listed_first_is_kept() -> None:
    base, target, masks = _case()

    def fit(k: int, mu_storage: str | None, under_detail: bool, coding: str | None = None):  # noqa: ANN202, ARG001
        return base, quantise_coefficients(_SHA, np.full(k, 1.0 if coding == "packed" else 2.0)), target * 0.9

    result = encode_layers(base, target * 0.5, target, masks, bytes_budget=40, basis_fit=fit, basis_count=75,
                           basis_variants=("packed", "coded"))
    assert result.record.basis.coefficients()[0] == pytest.approx(1.0, rel=0.01)


def test_a_fit_whose_coefficients_all_round_to_zero_is_the_base_alone() -> None:
    """The joint fit may find no coefficients best (a material unlike the training ones); no layer then survives
    quantisation, and the candidate is the base, sized and decoded as one (an rd run on a fold model raised)."""
    base, target, masks = _case()

    def fit(k: int, mu_storage: str | None, under_detail: bool, coding: str | None = None):  # noqa: ANN202, ARG001
        return base, None, target * 0.9

    result = encode_layers(base, target * 0.5, target, masks, bytes_budget=100, basis_fit=fit, basis_count=75,
                           basis_variants=("packed", "coded"))
    assert getattr(result.record, "basis", None) is None
    assert np.allclose(result.record.mu, base.mu)
    base_only = {p.distortion for p in result.points if p.option[1] is None}
    assert len(base_only) == 1  # every k, every coding: the base's own error (its decode, not the fit's mapped)


def test_the_chosen_record_is_the_lowest_error_that_fits_even_off_the_hull() -> None:
    """A point inside the convex hull that fits the budget beats the hull points that do."""
    from brdfcodec.codec.rate import RatePoint

    points = [RatePoint(10, 8.0, True, (1, None, None), None), RatePoint(20, 6.0, True, (2, None, None), None),
              RatePoint(40, 2.0, False, (3, None, None), None)]
    assert [i for i, _, _ in lagrangian_hull([(p.rate, p.distortion) for p in points])] == [0, 2]
    assert lowest_distortion(points, 30) == 1
    assert lowest_distortion(points, 40) == 2
    with pytest.raises(ValueError, match="no candidate fits 9 bytes"):
        lowest_distortion(points, 9)


def test_an_error_target_keeps_the_smallest_record_of_either_coding() -> None:
    from brdfcodec.representation import network_input_from_table

    values = np.full((3, 90, 90, 180), 0.05)
    mask = np.ones(values.shape, dtype=bool)
    inputs, input_mask = network_input_from_table(values, mask)
    base = LatentRecord("m", np.zeros(8), np.ones(8))

    def fit(k: int, mu_storage: str | None, under_detail: bool, coding: str | None = None):  # noqa: ANN202, ARG001
        # coded meets the target from 16 coefficient bytes, packed only with all 75
        exact = (coding == "coded" and k >= 16) or (coding == "packed" and k >= 75)
        mapped = inputs if exact else inputs * np.float32(0.7)
        return base, quantise_coefficients(_SHA, np.ones(k)), mapped.astype(np.float32)

    result = encode_layers(base, inputs * np.float32(0.7), inputs, input_mask.astype(np.float32), values=values,
                           mask=mask, max_relae=0.01, basis_fit=fit, basis_count=75, basis_variants=("packed", "coded"))
    assert result.record.basis.count == 16 and result.record.detail is None


def test_the_default_options_compare_both_first_vectors_and_both_codings() -> None:
    from brdfcodec.codec.encoding import EncodeOptions

    options = EncodeOptions(bytes_budget=64)
    assert options.basis_coding == "auto" and options.variants(8) == ("8", "0")
    assert options.variants(0) == ()  # no linear path: the coefficients start at the first vector anyway
    assert EncodeOptions(bytes_budget=64, basis_coding="int8").variants(8) == ()  # int8 layers: as before
    assert EncodeOptions(detail_step=0.5).variants(8) == ()  # no rate control, no candidates


@pytest.mark.slow
@pytest.mark.parametrize("budget", [16, 32])
def test_auto_coding_is_no_worse_than_either_coding_alone(analytic_tables, budget: int) -> None:
    """The shipped model on an analytic material: the default record's kept-slice error is at most that of the
    records made with --basis-coding packed and with coded (rate control measures both, and more)."""
    from brdfcodec.codec import BrdfEncoder
    from brdfcodec.representation import network_input_from_table

    brdf = analytic_tables["green-satin"]
    inputs, mask = network_input_from_table(brdf.values, brdf.mask)
    errors = {}
    for coding in ("auto", "packed", "coded"):
        encoder = BrdfEncoder(effort=1, bytes=budget, basis_coding=coding)
        record = encoder.encode(brdf, name="m")
        assert record.meta["rate"]["record_bytes"] <= budget
        mapped = np.clip(encoder.decoder.mapped_record(record), 0.0, None)
        errors[coding] = float((np.abs(mapped - inputs) * mask).sum())
    assert errors["auto"] <= min(errors["packed"], errors["coded"]) * (1 + 1e-6), errors
