"""Rate control is monotone in the budget (issue 39, 2): a larger budget never returns a worse record."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.codec.rate import encode_layers, layered_mapped
from brdfcodec.conventions import NETWORK_INPUT_SHAPE
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.layers.basis import quantise_coefficients

_BASIS_COUNT = 75


def _slice_error(mapped: np.ndarray, target: np.ndarray) -> float:
    return float(np.abs(np.clip(mapped, 0.0, None) - target).sum())


def _case(gain: float):
    """A base 1 % (``gain``) away from what basis coefficients give, whatever their number (as on the real
    ``paper_white``, where 13 to 53 coefficients all lowered the kept-slice error by 1.1 %)."""
    target = np.broadcast_to(np.linspace(0.2, 0.8, NETWORK_INPUT_SHAPE[-1], dtype=np.float32),
                             NETWORK_INPUT_SHAPE).copy()
    base_mapped = (target + 0.1).astype(np.float32)
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", np.zeros(8, np.float32), np.ones(8, np.float32), {})

    def basis_fit(k: int, mu_storage, under_detail: bool):
        layer = quantise_coefficients("0" * 64, np.linspace(0.1, 1.0, k))
        return base, layer, (base_mapped - gain * 0.1).astype(np.float32)

    return base, base_mapped, target, masks, basis_fit


@pytest.mark.parametrize("latent_itemsize", [2, 4])
def test_a_larger_budget_never_returns_the_base_alone_when_a_smaller_one_did_better(latent_itemsize: int) -> None:
    base, base_mapped, target, masks, basis_fit = _case(gain=0.01)
    errors = []
    for budget in (24, 28, 32, 36, 40, 44, 48, 56, 64, 80, 100, 128):
        result = encode_layers(base, base_mapped, target, masks, bytes_budget=budget, latent_itemsize=latent_itemsize,
                               basis_fit=basis_fit, basis_count=_BASIS_COUNT)
        with_basis = getattr(result.record, "basis", None) is not None
        mapped = layered_mapped(basis_fit(1, None, False)[2] if with_basis else base_mapped, result.record)
        errors.append((budget, _slice_error(mapped, target)))
    worse = [(a, b) for a, b in zip(errors, errors[1:]) if b[1] > a[1]]
    assert not worse, f"a larger budget returned a worse record: {worse[:3]}"


@pytest.mark.slow
def test_a_ladder_of_budgets_on_real_encodes_is_monotone(analytic_tables) -> None:
    """The shipped model, effort 1, float16 latents, several materials: along a ladder of budgets the kept-slice
    error rate control ranks by never rises, nor (beyond float rounding) the measured full-table RelAE."""
    from brdfcodec.codec import BrdfEncoder, measure
    from brdfcodec.representation import network_input_from_table

    budgets = (24, 32, 48, 64, 96, 128, 256, 1024)
    encoders = [BrdfEncoder(effort=1, bytes=b, latent_dtype="float16") for b in budgets]
    decoder = encoders[0].decoder
    for name in ("gold", "green-satin", "white-matte"):
        brdf = analytic_tables[name]
        inputs, mask = network_input_from_table(brdf.values, brdf.mask)
        ladder = []
        for budget, encoder in zip(budgets, encoders):
            record = measure(encoder.encode(brdf, name=name), decoder, brdf)
            kept = float((np.abs(np.clip(decoder.mapped_record(record), 0.0, None) - inputs) * mask).sum())
            ladder.append((budget, kept, record.meta["relae"]["mapped"]))
        for (small, kept_small, relae_small), (large, kept_large, relae_large) in zip(ladder, ladder[1:]):
            assert kept_large <= kept_small * (1 + 1e-6), (name, small, large, ladder)
            assert relae_large <= relae_small * (1 + 1e-3), (name, small, large, ladder)
