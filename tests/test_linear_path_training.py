"""Training the decoder's linear path (TrainConfig.linear_path_rate): float32 while training, float16 once exported."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch

from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.models.network import BetaVAE, linear_path_trainable
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.trainer import train

LINEAR_TINY = dataclasses.replace(TINY_CONFIG, linear_basis=True)
PATH = ("basis_mean", "basis_components")


def test_config_refuses_a_negative_or_non_finite_rate() -> None:
    for bad in (-0.1, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="linear_path_rate"):
            TrainConfig(linear_path_rate=bad)


def test_trainable_path_keeps_its_keys_and_rounds_back_to_float16() -> None:
    torch.manual_seed(0)
    model = BetaVAE(LINEAR_TINY)
    for name in PATH:
        getattr(model.decoder, name).copy_(torch.randn_like(getattr(model.decoder, name)))
    keys = list(model.state_dict())
    before = {name: getattr(model.decoder, name).clone() for name in PATH}
    made = linear_path_trainable(model.decoder)
    assert [p.dtype for p in made] == [torch.float32, torch.float32]
    assert all(isinstance(getattr(model.decoder, name), torch.nn.Parameter) for name in PATH)
    assert list(model.state_dict()) == keys  # same names, same order: checkpoints and export read them alike
    assert linear_path_trainable(model.decoder)[1] is made[1]  # a second call changes nothing
    for name in PATH:
        assert torch.equal(getattr(model.decoder, name).half(), before[name])
    z = torch.randn(2, LINEAR_TINY.latent_dim)
    out = model.decoder.unbounded(z)
    out.sum().backward()
    assert made[1].grad is not None and made[1].grad.abs().sum() > 0
    with torch.no_grad():
        made[1].add_(1e-3 * torch.randn_like(made[1]))
    exported = BetaVAE(LINEAR_TINY)
    exported.load_state_dict(model.state_dict())
    assert exported.decoder.basis_components.dtype == torch.float16
    assert torch.equal(exported.decoder.basis_components, made[1].detach().half())


def test_a_model_without_a_linear_path_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no linear path"):
        linear_path_trainable(BetaVAE(TINY_CONFIG).decoder)
    # The trainer refuses it before it reads the data or makes the run folder.
    with pytest.raises(ValueError, match="needs a model with a linear path"):
        train(tmp_path / "absent.h5", tmp_path / "run", model_config=TINY_CONFIG,
              train_config=TrainConfig(linear_path_rate=0.1), progress=False)
    assert not (tmp_path / "run").exists()


@pytest.mark.slow  # > 10 s on 2 cores
def test_the_path_moves_only_when_trained_at_its_own_rate_and_resumes(
        analytic_training_set: Path, tmp_path: Path) -> None:
    dataset = analytic_training_set
    base = TrainConfig(epochs=2, batch_size=4, learning_rate=1e-3, warmup_epochs=1, eval_every=1,
                       checkpoint_every=1, seed=7)
    trained = TrainConfig(**{**base.to_dict(), "linear_path_rate": 0.5})
    train(dataset, tmp_path / "frozen", model_config=LINEAR_TINY, train_config=base, progress=False)
    train(dataset, tmp_path / "trained", model_config=LINEAR_TINY, train_config=trained, progress=False)
    frozen = torch.load(tmp_path / "frozen" / "checkpoint.pt", weights_only=False)
    moved = torch.load(tmp_path / "trained" / "checkpoint.pt", weights_only=False)
    # Same PCA start (same data and seed); only the trained run's path changed.
    start = frozen["model"]["decoder.basis_components"]
    assert start.dtype == torch.float16
    path = moved["model"]["decoder.basis_components"]
    assert path.dtype == torch.float32 and not torch.equal(path.half(), start)
    groups = moved["optimizer"]["param_groups"]
    assert groups[-1]["lr_scale"] == 0.5 and groups[-1]["lr"] == pytest.approx(0.5 * groups[0]["lr"])
    assert "lr_scale" not in groups[0]
    # Resuming a trainable path (float32 in the checkpoint) continues it exactly.
    split = tmp_path / "split"
    first = TrainConfig(**{**trained.to_dict(), "time_limit_s": 0.0})
    assert train(dataset, split, model_config=LINEAR_TINY, train_config=first, progress=False).epochs_done == 1
    train(dataset, split, model_config=LINEAR_TINY, train_config=trained, resume=True, progress=False)
    resumed = torch.load(split / "checkpoint.pt", weights_only=False)
    assert torch.allclose(resumed["model"]["decoder.basis_components"], path, rtol=1e-5, atol=1e-6)
