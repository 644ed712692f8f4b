"""Factor supervision of the latent by analytic materials of known factors (issue 50, item 3)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from brdfcodec.datasets.analytic import (
    FACTOR_ALPHA_RANGE,
    FACTOR_NAMES,
    SATURATION_FACTOR,
    factor_material,
    sample_factor_materials,
)
from brdfcodec.datasets.hdf5 import build_dataset
from brdfcodec.datasets.sources import analytic_sources
from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.models.loss import beta_norm
from brdfcodec.models.network import BetaVAE
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.factor_supervision import (
    build_factor_pool,
    factor_supervision_loss,
    factor_targets,
    factor_weights,
)
from brdfcodec.training.trainer import _global_batches, train

SUPERVISED = TrainConfig(epochs=6, batch_size=4, learning_rate=3e-3, warmup_epochs=1, eval_every=1,
                         checkpoint_every=1, seed=7, keep="last", factor_weight=1000.0, factor_batch=4,
                         factor_materials=12, factor_seed=5)


def test_targets_standardise_each_factor_and_hold_the_free_dimensions_at_zero() -> None:
    factors = np.array([[0.0, 0.5, 1.0, 0.25, 0.75, 0.1, 0.9]])
    targets = factor_targets(factors, 8)
    assert targets.shape == (1, 8) and targets.dtype == np.float32
    np.testing.assert_allclose(targets[0, :7], (factors[0] - 0.5) * math.sqrt(12), rtol=1e-6)
    assert targets[0, 7] == 0
    # A uniform factor becomes mean 0, variance 1 (the prior's).
    drawn = sample_factor_materials(400, seed=3).factors
    standardised = factor_targets(drawn, 7)
    assert np.abs(standardised.mean(0)).max() < 0.15 and np.abs(standardised.var(0) - 1).max() < 0.15


def test_targets_refuse_a_latent_smaller_than_the_factors_and_values_outside_0_1() -> None:
    with pytest.raises(ValueError, match="at least 7"):
        factor_targets(np.full((2, 7), 0.5), 6)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        factor_targets(np.full((2, 7), 1.5), 8)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        factor_targets(np.full((2, 7), np.nan), 8)


def test_loss_is_the_batch_mean_of_the_squared_distance_summed_over_dimensions() -> None:
    targets = torch.tensor([[1.0, -1.0, 0.0], [0.0, 0.0, 0.0]])
    mu = torch.tensor([[1.0, 1.0, 0.0], [3.0, 0.0, 1.0]])
    # sample 0: 4; sample 1: 9 + 1 = 10; mean 7
    assert factor_supervision_loss(mu, targets).item() == pytest.approx(7.0)
    assert factor_supervision_loss(targets, targets).item() == 0
    with pytest.raises(ValueError, match="one shape"):
        factor_supervision_loss(mu[:, :2], targets)


def test_pool_holds_the_materials_inputs_and_targets_of_its_seed() -> None:
    pool = build_factor_pool(3, 11, 8)
    drawn = sample_factor_materials(3, seed=11)
    assert len(pool) == 3 and pool.seed == 11
    x, m = drawn.materials[2].kept_network_input()
    np.testing.assert_array_equal(pool.inputs[2].numpy(), x)
    np.testing.assert_array_equal(pool.masks[2].numpy(), m)
    np.testing.assert_array_equal(pool.targets.numpy(), factor_targets(drawn.factors, 8))


def test_config_validates_the_supervision_settings_and_round_trips() -> None:
    for bad in ({"factor_weight": -1.0}, {"factor_weight": math.inf}, {"factor_batch": 0}, {"factor_materials": 0}):
        with pytest.raises(ValueError, match="factor_"):
            TrainConfig(**bad)  # type: ignore[arg-type]
    assert TrainConfig.from_dict(json.loads(SUPERVISED.to_json())) == SUPERVISED
    assert len(FACTOR_NAMES) == 7


def test_supervision_draws_leave_the_plain_stream_alone() -> None:
    plain = list(_global_batches(10, TrainConfig(batch_size=4, seed=3), 0, 8))
    supervised = list(_global_batches(10, TrainConfig(batch_size=4, seed=3, factor_weight=1.0, factor_batch=3,
                                                      factor_materials=5), 0, 8))
    # The first batch's draws are the plain run's (later batches follow the extra draws of the ones before).
    assert "factor_rows" not in plain[0]
    for key in plain[0]:
        assert torch.equal(plain[0][key], supervised[0][key]), key
    rows = torch.cat([d["factor_rows"] for d in supervised])
    assert rows.shape == (3 * len(supervised),) and int(rows.min()) >= 0 and int(rows.max()) < 5
    assert all(d["factor_noise"].shape == (3, 8) for d in supervised)


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("factor-data") / "analytic.h5"
    build_dataset(path, analytic_sources(random_count=5), source_kind="analytic", description="analytic test set",
                  validation_fraction=0.2, seed=0, progress=False)
    return path


def _pool_loss(run: Path, config: TrainConfig) -> float:
    """The supervision loss of a run's kept weights on its whole pool (encoder means, no noise)."""
    model = BetaVAE(TINY_CONFIG)
    model.load_state_dict(torch.load(run / "best.pt", weights_only=True)["model"])
    model.eval()
    pool = build_factor_pool(config.factor_materials, config.factor_seed, TINY_CONFIG.latent_dim)
    with torch.no_grad():
        mu, _ = model.encoder(pool.inputs)
    return float(factor_supervision_loss(mu, pool.targets))


@pytest.mark.slow  # > 10 s on 2 cores
def test_a_supervised_run_logs_the_term_lowers_it_and_resumes_exactly(tiny_dataset: Path, tmp_path: Path) -> None:
    plain = TrainConfig(**{**SUPERVISED.to_dict(), "factor_weight": 0.0})
    train(tiny_dataset, tmp_path / "plain", model_config=TINY_CONFIG, train_config=plain, progress=False)
    train(tiny_dataset, tmp_path / "a", model_config=TINY_CONFIG, train_config=SUPERVISED, progress=False)
    log = [json.loads(line) for line in (tmp_path / "a" / "log.jsonl").read_text().splitlines()]
    plain_log = [json.loads(line) for line in (tmp_path / "plain" / "log.jsonl").read_text().splitlines()]
    assert all(r["factor"] == 0 for r in plain_log)
    assert all(math.isfinite(r["factor"]) and r["factor"] > 0 for r in log)
    # The logged loss holds the real batch's objective, the analytic batch's and the weighted term: it exceeds
    # the real batch's objective by at least the weighted term.
    weight = beta_norm(SUPERVISED.beta, TINY_CONFIG.latent_dim)
    for record in log:
        assert record["loss"] > record["recon"] + weight * record["kl"] + SUPERVISED.factor_weight * record["factor"]
    assert log[-1]["factor"] < log[0]["factor"]
    # Measured on the whole pool with the last weights, the supervised run is clearly nearer its targets than the
    # same run without the term.
    assert _pool_loss(tmp_path / "a", SUPERVISED) < 0.75 * _pool_loss(tmp_path / "plain", SUPERVISED)
    # Checkpoint and resume: stopped after its first epoch and resumed, it ends where the straight run does.
    first = TrainConfig(**{**SUPERVISED.to_dict(), "time_limit_s": 0.0})
    train(tiny_dataset, tmp_path / "split", model_config=TINY_CONFIG, train_config=first, progress=False)
    stored = json.loads((tmp_path / "split" / "run.json").read_text())["train_config"]
    assert TrainConfig.from_dict(stored).factor_weight == SUPERVISED.factor_weight
    train(tiny_dataset, tmp_path / "split", model_config=TINY_CONFIG, train_config=SUPERVISED, resume=True,
          progress=False)
    resumed = [json.loads(line) for line in (tmp_path / "split" / "log.jsonl").read_text().splitlines()]
    assert [r["loss"] for r in resumed] == pytest.approx([r["loss"] for r in log], rel=1e-5)
    other = TrainConfig(**{**SUPERVISED.to_dict(), "factor_seed": 6})
    with pytest.raises(ValueError, match="different train config"):
        train(tiny_dataset, tmp_path / "split", model_config=TINY_CONFIG, train_config=other, resume=True,
              progress=False)


def test_saturation_factor_adds_grey_colours_and_keeps_the_first_seven_factors() -> None:
    plain = sample_factor_materials(40, seed=9)
    varied = sample_factor_materials(40, seed=9, saturation=True)
    assert varied.names == (*FACTOR_NAMES, "saturation") and varied.factors.shape == (40, 8)
    np.testing.assert_array_equal(varied.factors[:, :7], plain.factors)
    # A non-metal's diffuse colour: saturation 0 is grey, the benchmark's materials keep saturation 0.7.
    base = [0.5, 0.2, 0.5, 0.5, 0.0, 0.0, 0.0]
    grey = np.asarray(factor_material([*base, 0.0]).diffuse)
    assert np.ptp(grey) < 1e-12 and grey.mean() > 0
    np.testing.assert_array_equal(factor_material([*base, 0.7]).diffuse, factor_material(base).diffuse)
    vivid = np.asarray(factor_material([*base, 1.0]).diffuse)
    assert np.ptp(vivid) > np.ptp(np.asarray(factor_material(base).diffuse))
    with pytest.raises(ValueError, match="saturation"):
        factor_material([*base, 0.5, 0.5])


def test_saturation_pool_ties_dimension_8_and_weights_the_hue_by_saturation() -> None:
    pool = build_factor_pool(6, seed=4, latent_dim=9, saturation=True)
    drawn = sample_factor_materials(6, seed=4, saturation=True)
    np.testing.assert_allclose(pool.targets[:, 7].numpy(), (drawn.factors[:, 7] - 0.5) * math.sqrt(12), rtol=1e-6)
    assert (pool.targets[:, 8] == 0).all()
    hue = FACTOR_NAMES.index("hue")
    np.testing.assert_allclose(pool.weights[:, hue].numpy(), np.minimum(1.0, drawn.factors[:, 7] / 0.7), rtol=1e-6)
    others = np.delete(pool.weights.numpy(), hue, axis=1)
    assert (others == 1).all()


def test_a_grey_material_s_hue_costs_nothing_in_the_weighted_loss() -> None:
    names = (*FACTOR_NAMES, SATURATION_FACTOR)
    hue = FACTOR_NAMES.index("hue")
    weights = factor_weights(np.array([[0.5] * 7 + [0.0], [0.5] * 7 + [0.35]]), names, 8)
    assert weights[0, hue] == 0 and weights[1, hue] == pytest.approx(0.5)
    targets = torch.from_numpy(factor_targets(np.array([[0.5] * 7 + [0.0]] * 2), 8))
    mu = targets.clone()
    mu[:, hue] += 1.0
    assert factor_supervision_loss(mu, targets, torch.from_numpy(weights)).item() == pytest.approx(0.25)
    assert factor_supervision_loss(mu, targets).item() == pytest.approx(1.0)


def test_without_saturation_the_weights_are_1_and_a_latent_of_7_is_enough() -> None:
    plain = build_factor_pool(3, seed=4, latent_dim=7)
    assert (plain.weights == 1).all()
    with pytest.raises(ValueError, match="at least 8"):
        build_factor_pool(2, seed=4, latent_dim=7, saturation=True)


def test_a_lower_alpha_min_draws_sharper_materials_from_the_same_factors() -> None:
    plain = sample_factor_materials(12, seed=6)
    sharp = sample_factor_materials(12, seed=6, alpha_min=0.01)
    np.testing.assert_array_equal(sharp.factors, plain.factors)
    roughness = FACTOR_NAMES.index("roughness")
    for factors, a, b in zip(plain.factors, plain.materials, sharp.materials, strict=True):
        u = factors[roughness]
        assert a.roughness == pytest.approx(0.03 * (0.6 / 0.03) ** u)
        assert b.roughness == pytest.approx(0.01 * (0.6 / 0.01) ** u)
    pool = build_factor_pool(2, seed=6, latent_dim=8, alpha_min=0.01)
    np.testing.assert_array_equal(pool.targets.numpy(), factor_targets(plain.factors[:2], 8))
    x, _ = sharp.materials[1].kept_network_input()
    np.testing.assert_array_equal(pool.inputs[1].numpy(), x)


def test_the_training_default_alpha_min_is_the_benchmark_s() -> None:
    assert TrainConfig().factor_alpha_min == FACTOR_ALPHA_RANGE[0]


@pytest.mark.parametrize("bad", [0.0, 0.6, -1.0])
def test_an_alpha_min_outside_0_to_0_6_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match="alpha_min"):
        factor_material([0.5] * 7, alpha_min=bad)
    with pytest.raises(ValueError, match="factor_alpha_min"):
        TrainConfig(factor_alpha_min=bad)
