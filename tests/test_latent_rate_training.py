"""Quantisation-aware latent and its rate in training (issue 48, item 3: R + λD with the codec's own R)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from brdfcodec.layers.coded_basis import coded_mu_codes, encode_integers
from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.models.loss import latent_rate
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.trainer import _global_batches, train

LAPLACE_SCALE = 0.5**0.5  # the format's unit prior (spread one latent unit), §4.9


def _cell_mass(value: float, step: float) -> float:
    """The unit Laplace prior's mass on [value − step/2, value + step/2], in binary64."""
    def cdf(t: float) -> float:
        return 0.5 * math.exp(t / LAPLACE_SCALE) if t < 0 else 1.0 - 0.5 * math.exp(-t / LAPLACE_SCALE)
    return cdf(value + step / 2) - cdf(value - step / 2)


@pytest.mark.parametrize("step", [0.5, 0.25, 0.125])
def test_the_rate_is_minus_the_log_of_the_prior_s_mass_on_the_cell(step: float) -> None:
    values = [0.0, 0.03, -0.2, 0.5, -1.7, 3.0, 6.5]
    rate = latent_rate(torch.tensor([values], dtype=torch.float64), step)[0]
    expected = [-math.log(_cell_mass(v, step)) for v in values]
    assert rate.tolist() == pytest.approx(expected, rel=1e-12)


def test_the_rate_stays_finite_with_a_finite_gradient_for_extreme_latents() -> None:
    mu = torch.tensor([[0.0, 1e-30, -1e-3, 40.0, -400.0, 1e6, -3e38, 7.0]], requires_grad=True)
    for dtype in (torch.float32, torch.float64):
        value = mu.to(dtype)
        rate = latent_rate(value, 0.25)
        assert torch.isfinite(rate).all()
        assert float(rate.detach().max()) <= -math.log(1e-12) + 1e-6  # floored, never infinite
        (gradient,) = torch.autograd.grad(rate.sum(), mu)
        assert torch.isfinite(gradient).all()
    # Away from the floor the rate pulls μ towards 0, as the prior does.
    small = torch.tensor([[0.6, -0.6]], requires_grad=True)
    (gradient,) = torch.autograd.grad(latent_rate(small, 0.25).sum(), small)
    assert gradient[0, 0] > 0 > gradient[0, 1]


def test_a_step_that_is_not_positive_is_refused() -> None:
    with pytest.raises(ValueError, match="step"):
        latent_rate(torch.zeros(1, 8), 0.0)


@pytest.mark.parametrize("grid", [1, 2, 3])
def test_on_the_grid_the_rate_is_the_coded_mu_s_bytes_less_the_coder_s_termination(grid: int) -> None:
    """The training's R is the codec's: μ on the grid 2^−g, coded by the format's coder under §4.9's prior,
    takes the rate's bits plus the termination: a few bits on average; a record's last byte can also end the
    stream early (never by a whole byte) or late (by two at most)."""
    rng = np.random.default_rng(grid)
    step = 2.0**-grid
    differences = []
    for _ in range(200):
        q = np.round(rng.normal(size=8) / step).astype(np.int64)
        bits = float(latent_rate(torch.tensor(q * step)[None], step).sum()) / math.log(2)
        differences.append(8 * len(encode_integers(q, coded_mu_codes(grid, 8))) - bits)
    assert 0.0 < float(np.mean(differences)) < 5.0
    assert -8.0 < min(differences) and max(differences) < 16.0


def test_the_config_checks_the_grid_and_the_weight_and_round_trips() -> None:
    config = TrainConfig(latent_grid=2, rate_weight=70.0)
    assert TrainConfig.from_dict(json.loads(config.to_json())) == config
    for bad in (-1, 6, 2.5):
        with pytest.raises(ValueError, match="latent_grid"):
            TrainConfig(latent_grid=bad)  # type: ignore[arg-type]
    for bad_weight in (-1.0, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="rate_weight"):
            TrainConfig(latent_grid=2, rate_weight=bad_weight)
    with pytest.raises(ValueError, match="needs latent_grid"):
        TrainConfig(rate_weight=1.0)


def test_the_grid_s_noise_is_drawn_last_and_leaves_the_plain_stream_alone() -> None:
    plain = list(_global_batches(10, TrainConfig(batch_size=4, seed=3, traversal_weight=1.0), 0, 8))
    noisy = list(_global_batches(10, TrainConfig(batch_size=4, seed=3, traversal_weight=1.0, latent_grid=2), 0, 8))
    assert "grid_noise" not in plain[0]
    for key in plain[0]:
        assert torch.equal(plain[0][key], noisy[0][key]), key
    noise = torch.cat([d["grid_noise"] for d in noisy])
    assert noise.shape == (8, 8)
    assert float(noise.abs().max()) <= 0.125 and float(noise.std()) > 0.02  # uniform of width 2^-2
    supervised = list(_global_batches(10, TrainConfig(batch_size=4, seed=3, latent_grid=1, factor_weight=1.0,
                                                      factor_batch=3, factor_materials=5), 0, 8))
    assert all(d["factor_grid_noise"].shape == (3, 8) for d in supervised)
    assert float(torch.cat([d["factor_grid_noise"] for d in supervised]).abs().max()) <= 0.25


@pytest.mark.slow  # > 10 s on 2 cores
def test_a_run_with_a_rate_logs_it_and_a_heavier_weight_spends_fewer_bits(analytic_training_set: Path,
                                                                           tmp_path: Path) -> None:
    base = dict(epochs=6, batch_size=4, learning_rate=3e-3, warmup_epochs=1, eval_every=3, checkpoint_every=3,
                seed=7, keep="last")
    logs = {}
    for label, extra in {"plain": {}, "noisy": {"latent_grid": 2},
                         "rate": {"latent_grid": 2, "rate_weight": 3e4}}.items():
        train(analytic_training_set, tmp_path / label, model_config=TINY_CONFIG, train_config=TrainConfig(**base, **extra),
              progress=False)
        logs[label] = [json.loads(line) for line in (tmp_path / label / "log.jsonl").read_text().splitlines()]
    assert all(r["rate_bits"] == 0 for r in logs["plain"])
    assert all(math.isfinite(r["rate_bits"]) and r["rate_bits"] > 0 for r in logs["noisy"] + logs["rate"])
    # With the same draws until the rate's gradient acts, the weighted run ends with a cheaper latent.
    assert logs["rate"][-1]["rate_bits"] < 0.8 * logs["noisy"][-1]["rate_bits"]
    stored = json.loads((tmp_path / "rate" / "run.json").read_text())["train_config"]
    assert TrainConfig.from_dict(stored).rate_weight == 3e4


def test_the_model_card_says_the_latent_was_trained_on_a_grid_and_at_what_rate_weight() -> None:
    import copy

    from brdfcodec.models.registry import default_model_folder
    from brdfcodec.training.card import render_model_card

    manifest = json.loads((default_model_folder() / "model.json").read_text())
    assert "uniform noise" not in render_model_card(manifest)  # the shipped model was trained without
    noisy = copy.deepcopy(manifest)
    noisy["info"]["train_config"].update(latent_grid=2, rate_weight=0.0)
    assert "z with uniform noise of width 2^−2 (the coded μ's rounding on that grid)." in render_model_card(noisy)
    noisy["info"]["train_config"]["rate_weight"] = 70.0
    assert "and μ's code length there weighted 70 (D + λR)." in render_model_card(noisy)
