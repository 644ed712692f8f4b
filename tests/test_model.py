"""The β-VAE networks, loss and augmentation (tiny models, CPU)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from brdfcodec.conventions import MAPPED_MAX, NETWORK_INPUT_SHAPE
from brdfcodec.models.config import PAPER_CONFIG, SMALL_CONFIG, TINY_CONFIG, ModelConfig
from brdfcodec.models.loss import beta_norm, beta_vae_loss, kl_per_dimension
from brdfcodec.models.network import BetaVAE, initialise_linear_basis
from brdfcodec.models.pca import fit_pca
from brdfcodec.representation import clamp_mapped, map_values, select_kept_slices
from brdfcodec.representation import to_network_layout as network_input
from brdfcodec.representation.mask import kept_slice_horizon_mask
from brdfcodec.training.augment import COLOUR_PERMUTATIONS, mix_physical, permute_colours


@pytest.fixture(scope="module")
def tiny_model() -> BetaVAE:
    torch.manual_seed(0)
    return BetaVAE(TINY_CONFIG).eval()


def test_shapes_and_output_range(tiny_model: BetaVAE) -> None:
    x = torch.rand(3, *NETWORK_INPUT_SHAPE)
    recon, mu, logvar = tiny_model(x)
    assert recon.shape == (3, *NETWORK_INPUT_SHAPE)
    assert mu.shape == logvar.shape == (3, TINY_CONFIG.latent_dim)
    assert (recon >= 0).all() and (recon <= MAPPED_MAX).all()


@pytest.mark.parametrize("scale", [0.0, 3.0, 50.0, 1e6])
def test_extreme_latents_decode_to_finite_values_in_the_mapped_domain(tiny_model: BetaVAE, scale: float) -> None:
    z = torch.randn(4, TINY_CONFIG.latent_dim) * scale
    with torch.no_grad():
        out = tiny_model.decoder(z)
    assert torch.isfinite(out).all() and (out >= 0).all() and (out <= MAPPED_MAX).all()


def test_float16_decoding_stays_finite(tiny_model: BetaVAE) -> None:
    z = torch.randn(2, TINY_CONFIG.latent_dim) * 10
    half = BetaVAE(TINY_CONFIG).eval()
    half.load_state_dict(tiny_model.state_dict())
    half = half.to(torch.bfloat16)  # CPU lacks float16 convolutions; bfloat16 has float16's failure modes and worse
    with torch.no_grad():
        out16 = half.decoder(z.to(torch.bfloat16)).float()
        out32 = tiny_model.decoder(z)
    assert torch.isfinite(out16).all()
    assert (out16 - out32).abs().max() < 0.1 * MAPPED_MAX


def test_eval_mode_uses_the_mean_and_train_mode_samples(tiny_model: BetaVAE) -> None:
    x = torch.rand(2, *NETWORK_INPUT_SHAPE)
    a, mu, _ = tiny_model(x)
    b, _, _ = tiny_model(x)
    torch.testing.assert_close(a, b)
    torch.testing.assert_close(a, tiny_model.decoder(mu))
    tiny_model.train()
    try:
        noise = torch.zeros(2, TINY_CONFIG.latent_dim)
        c, _, _ = tiny_model(x, noise)
        torch.testing.assert_close(c, a, atol=1e-5, rtol=1e-5)  # group norm: train = eval
    finally:
        tiny_model.eval()


def test_config_json_round_trip_and_validation() -> None:
    for config in (PAPER_CONFIG, SMALL_CONFIG, TINY_CONFIG):
        assert ModelConfig.from_dict(json.loads(config.to_json())) == config
    with pytest.raises(ValueError, match="unknown"):
        ModelConfig.from_dict({"latent": 3})
    with pytest.raises(ValueError, match="multiple of 8"):
        ModelConfig(encoder_channels=(12, 16, 16))
    with pytest.raises(ValueError, match="norm"):
        ModelConfig(norm="layer")  # type: ignore[arg-type]


def test_paper_config_is_paper_sized() -> None:
    model = BetaVAE(PAPER_CONFIG)
    megabytes = sum(p.numel() for p in model.parameters()) * 4 / 1e6
    assert 70 < megabytes < 95  # the paper reports 78.9 MB
    state = BetaVAE(SMALL_CONFIG).decoder.state_dict()
    small_decoder = sum(t.numel() * t.element_size() for t in state.values()) / 1e6
    assert small_decoder <= 10.0


def test_loss_is_masked_and_kl_matches_closed_form() -> None:
    torch.manual_seed(1)
    target = torch.rand(2, *NETWORK_INPUT_SHAPE)
    recon = target.clone()
    mask = torch.ones_like(target, dtype=torch.bool)
    mask[:, :, :10] = False
    recon[:, :, :10] = 99.0  # garbage where invalid
    mu = torch.tensor([[0.0, 1.0], [2.0, 0.0]])
    logvar = torch.tensor([[0.0, 0.0], [0.0, float(np.log(4.0))]])
    terms = beta_vae_loss(recon, target, mask, mu, logvar, beta=12.0)
    assert terms.recon.item() == 0.0
    kl = kl_per_dimension(mu, logvar)
    expected = torch.tensor([[0.0, 0.5], [2.0, 0.5 * (4 - 1 - np.log(4.0))]])
    torch.testing.assert_close(kl, expected.float())
    assert beta_norm(12.0, 8) == pytest.approx(12 * 8 / (63 * 90 * 90))
    assert terms.loss.item() == pytest.approx(beta_norm(12.0, 2) * kl.sum(1).mean().item(), rel=1e-5)
    recon2 = target + 0.1 * mask
    l1 = beta_vae_loss(recon2, target, mask, mu, logvar, beta=0.0, recon="l1").recon.item()
    l2 = beta_vae_loss(recon2, target, mask, mu, logvar, beta=0.0, recon="l2").recon.item()
    n_valid = mask[0].sum().item()
    assert l1 == pytest.approx(0.1 * n_valid, rel=1e-4) and l2 == pytest.approx(0.01 * n_valid, rel=1e-4)


def test_training_step_on_extreme_inputs_has_finite_gradients() -> None:
    torch.manual_seed(2)
    model = BetaVAE(TINY_CONFIG).train()
    x = torch.zeros(2, *NETWORK_INPUT_SHAPE)
    x[0] = MAPPED_MAX  # everything at the top of the mapped domain
    x[1, :, 0, 0] = 4.9  # one huge grazing spike on black
    mask = torch.ones_like(x, dtype=torch.bool)
    recon, mu, logvar = model(x)
    beta_vae_loss(recon, x, mask, mu, logvar, beta=12.0).loss.backward()
    for parameter in model.parameters():
        assert parameter.grad is not None and torch.isfinite(parameter.grad).all()


def test_colour_permutation_moves_whole_colour_planes() -> None:
    rng = np.random.default_rng(3)
    kept = rng.random((2, 3, 90, 90, 21)).astype(np.float32)
    batch = torch.from_numpy(network_input(kept))
    assert COLOUR_PERMUTATIONS[0].tolist() == [0, 1, 2]
    same = permute_colours(batch, torch.tensor([0, 0]))
    torch.testing.assert_close(same, batch)
    swap = int(np.flatnonzero([p.tolist() == [2, 1, 0] for p in COLOUR_PERMUTATIONS])[0])
    out = permute_colours(batch, torch.tensor([swap, 0]))
    expected = network_input(kept[:, ::-1].copy())
    torch.testing.assert_close(out[0], torch.from_numpy(expected[0]))
    torch.testing.assert_close(out[1], batch[1])
    masks = permute_colours(batch > 0.5, torch.tensor([swap, swap]))
    assert masks.dtype == torch.bool


def test_physical_mixing_blends_reflectance() -> None:
    rng = np.random.default_rng(4)
    a, b = rng.lognormal(0, 2, (2, 3, 90, 90, 180))
    map_a = torch.from_numpy(network_input(select_kept_slices(map_values(a))).astype(np.float32))[None]
    map_b = torch.from_numpy(network_input(select_kept_slices(map_values(b))).astype(np.float32))[None]
    torch.testing.assert_close(mix_physical(map_a, map_b, torch.tensor([1.0])), map_a, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(mix_physical(map_a, map_b, torch.tensor([0.0])), map_b, rtol=1e-4, atol=1e-5)
    blend = network_input(select_kept_slices(map_values(0.25 * a + 0.75 * b))).astype(np.float32)
    torch.testing.assert_close(mix_physical(map_a, map_b, torch.tensor([0.25]))[0], torch.from_numpy(blend),
                               rtol=1e-4, atol=1e-4)


def test_replace_keeps_configs_frozen() -> None:
    bigger = dataclasses.replace(TINY_CONFIG, latent_dim=16)
    assert BetaVAE(bigger).encoder.head.out_features == 32


@pytest.fixture(scope="module")
def basis_model_and_data() -> tuple[BetaVAE, torch.Tensor]:
    torch.manual_seed(5)
    data = torch.rand(12, *NETWORK_INPUT_SHAPE) * 2
    data = data * torch.from_numpy(network_input(np.repeat(kept_slice_horizon_mask()[None], 3, axis=0)))
    config = dataclasses.replace(TINY_CONFIG, linear_basis=True, latent_dim=4)
    model = BetaVAE(config)
    initialise_linear_basis(model, data)
    return model.eval(), data


def test_linear_basis_starts_as_pca(basis_model_and_data: tuple[BetaVAE, torch.Tensor]) -> None:
    model, data = basis_model_and_data
    with torch.no_grad():
        recon, mu, _ = model(data)
    pca = fit_pca(data.numpy(), 4)
    expected = clamp_mapped(pca.decode(pca.encode(data.numpy())))  # the network's output is clamped
    np.testing.assert_allclose(recon.numpy(), expected, atol=2e-2)  # float16 storage of the basis
    # μ starts as whitened coefficients: unit variance over the fitting set, matching the prior.
    np.testing.assert_allclose(mu.std(0, unbiased=True).numpy(), 1.0, rtol=1e-3)


@pytest.mark.parametrize("scale", [3.0, 50.0, 1e4])
def test_linear_basis_extreme_latents_stay_in_domain(
    basis_model_and_data: tuple[BetaVAE, torch.Tensor], scale: float
) -> None:
    model, _ = basis_model_and_data
    with torch.no_grad():
        out = model.decoder(torch.randn(3, 4) * scale)
    assert torch.isfinite(out).all() and (out >= 0).all() and (out <= MAPPED_MAX).all()


def test_training_mode_returns_unbounded_output(basis_model_and_data: tuple[BetaVAE, torch.Tensor]) -> None:
    model, data = basis_model_and_data
    z = torch.full((1, 4), 1e3)
    assert (model.decoder.unbounded(z).abs() > MAPPED_MAX).any()  # the loss sees how far off it is
    with pytest.raises(ValueError, match="no linear basis"):
        initialise_linear_basis(BetaVAE(TINY_CONFIG), data)
