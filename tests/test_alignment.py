"""Aligning a model's latent axes with the analytic factors (brdfcodec.training.alignment)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from brdfcodec.models.alignment import AlignmentError, factor_rotation, rotate_latent
from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.models.network import BetaVAE, initialise_linear_basis
from brdfcodec.models.store import compact_encoder_tensors, expand_encoder_tensors
from brdfcodec.training.alignment import align_to_factors


def random_rotation(dims: int, seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(dims, dims)))
    return q * np.sign(np.diag(r))


@pytest.fixture(scope="module")
def model() -> BetaVAE:
    """A tiny model with a fitted linear path and non-zero heads (untrained heads start at zero)."""
    torch.manual_seed(0)
    config = dataclasses.replace(TINY_CONFIG, linear_basis=True)
    network = BetaVAE(config).eval()
    inputs = torch.rand(12, 63, 90, 90) * 2
    initialise_linear_basis(network, inputs)
    with torch.no_grad():
        network.encoder.head.weight.normal_(0, 0.1)
        network.encoder.head.bias.normal_(0, 0.1)
    return network


def test_rotation_recovers_a_known_turn_and_orders_the_rest_by_variance() -> None:
    rng = np.random.default_rng(1)
    factors = rng.random((4000, 3))
    noise_scales = np.array([1.0, 0.2])  # the two dimensions the factors leave: variance 1 and 0.04
    latent = np.concatenate([factors - 0.5, rng.normal(size=(4000, 2)) * noise_scales], axis=1)
    turn = random_rotation(5, 2)
    rotation = factor_rotation(latent @ turn.T, factors)
    assert np.allclose(rotation @ rotation.T, np.eye(5), atol=1e-12)
    recovered = rotation @ turn  # ≈ the identity on the factors' dimensions
    assert np.allclose(np.abs(recovered[:3, :3]), np.eye(3), atol=0.05)
    assert (np.diag(recovered[:3, :3]) > 0).all()  # positive with each factor
    variances = ((latent @ turn.T) @ rotation.T)[:, 3:].var(axis=0)
    assert variances[0] > variances[1] * 10  # the leftover dimensions in decreasing variance


@pytest.mark.parametrize(("codes", "factors", "message"), [
    (np.zeros((20, 2)), np.zeros((20, 3)), "3 factors cannot be aligned with 2"),
    (np.zeros((20, 2)), np.zeros((19, 2)), "same N"),
    (np.zeros((2, 2)), np.ones((2, 2)), "more than 2 materials"),
    (np.full((20, 2), np.nan), np.random.default_rng(0).random((20, 2)), "finite"),
    (np.zeros((20, 2)), np.ones((20, 2)), "vary"),
])
def test_rotation_refuses_what_cannot_define_one(codes: np.ndarray, factors: np.ndarray, message: str) -> None:
    with pytest.raises(AlignmentError, match=message):
        factor_rotation(codes, factors)


@pytest.mark.slow
def test_a_rotated_model_decodes_the_rotated_code_as_before(model: BetaVAE) -> None:
    rotated = BetaVAE(model.config).eval()
    rotated.load_state_dict(model.state_dict())
    rotation = random_rotation(model.config.latent_dim, 3)
    rotate_latent(rotated.encoder, rotated.decoder, rotation)
    x = torch.rand(3, 63, 90, 90)
    with torch.no_grad():
        mu, logvar = model.encoder(x)
        mu_r, logvar_r = rotated.encoder(x)
        matrix = torch.as_tensor(rotation, dtype=torch.float32)
        assert torch.allclose(mu_r, mu @ matrix.T, atol=1e-4)
        assert torch.allclose(logvar_r, logvar @ (matrix * matrix).T, atol=1e-4)
        before, after = model.decoder.unbounded(mu), rotated.decoder.unbounded(mu_r)
    # the linear path is stored in float16, so the rotated one is rounded again: a few 1e-3 of its range
    assert float((after - before).abs().max()) < 5e-3 * float(before.abs().max())
    assert not torch.allclose(mu_r, mu, atol=1e-3)


def test_the_compact_encoder_rebuilds_a_rotated_projection(model: BetaVAE) -> None:
    rotated = BetaVAE(model.config).eval()
    rotated.load_state_dict(model.state_dict())
    rotate_latent(rotated.encoder, rotated.decoder, random_rotation(model.config.latent_dim, 4))
    rebuilt = expand_encoder_tensors(compact_encoder_tensors(rotated.encoder.state_dict()),
                                     rotated.decoder.state_dict())
    kept = rotated.encoder.basis_projection
    assert float((rebuilt["basis_projection"] - kept).abs().max()) < 2e-3 * float(kept.abs().max())


def test_rotate_latent_refuses_a_matrix_that_is_not_a_rotation(model: BetaVAE) -> None:
    dims = model.config.latent_dim
    with pytest.raises(AlignmentError, match="orthogonal"):
        rotate_latent(model.encoder, None, 2 * np.eye(dims))
    with pytest.raises(AlignmentError, match=f"{dims} × {dims}"):
        rotate_latent(None, model.decoder, np.eye(dims + 1))


@pytest.mark.slow
def test_alignment_makes_the_first_dimensions_follow_the_factors(model: BetaVAE) -> None:
    aligned = BetaVAE(model.config).eval()
    aligned.load_state_dict(model.state_dict())
    result = align_to_factors(aligned, materials=24, seed=5)
    assert result.factor_names[:2] == ("albedo", "hue") and len(result.correlation) == 7
    assert np.allclose(result.rotation @ result.rotation.T, np.eye(model.config.latent_dim), atol=1e-9)
    assert (result.correlation > 0).all()  # each aligned dimension grows with its factor
    stored = result.as_dict()
    assert stored["materials"] == 24 and stored["seed"] == 5 and len(stored["rotation"]) == 8
    with pytest.raises(AlignmentError, match="more than 8 materials"):
        align_to_factors(aligned, materials=8)


@pytest.mark.slow
def test_measuring_without_turning_keeps_the_weights_and_reports_the_present_axes(model: BetaVAE) -> None:
    kept = BetaVAE(model.config).eval()
    kept.load_state_dict(model.state_dict())
    before = {key: value.clone() for key, value in kept.state_dict().items()}
    result = align_to_factors(kept, materials=24, seed=5, rotate=False)
    assert np.array_equal(result.rotation, np.eye(model.config.latent_dim))
    assert all(torch.equal(before[key], value) for key, value in kept.state_dict().items())
    # The correlations are those of the present axes with the factors.
    from brdfcodec.training.alignment import factor_codes

    with torch.no_grad():
        codes, factors, _ = factor_codes(kept.encoder, 24, 5)
    expected = [np.corrcoef(codes[:, i], factors[:, i])[0, 1] for i in range(factors.shape[1])]
    assert np.allclose(result.correlation, expected)
