"""Stochastic weight averaging in training (TrainConfig.average_from_epoch): what is averaged, kept and resumed."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.training.card import render_model_card
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.trainer import train

LINEAR_TINY = dataclasses.replace(TINY_CONFIG, linear_basis=True)


def test_config_refuses_a_start_outside_the_schedule() -> None:
    for bad in (-1, 4):
        with pytest.raises(ValueError, match="average_from_epoch"):
            TrainConfig(epochs=3, average_from_epoch=bad)
    assert TrainConfig(epochs=3, average_from_epoch=3).average_from_epoch == 3


def test_the_card_names_the_average_only_when_the_kept_weights_are_one() -> None:
    manifest = json.loads((Path(__file__).parents[1] / "brdfcodec" / "data" / "models" / "default" / "model.json")
                          .read_text())
    info = manifest["info"]
    averaged = {**manifest, "info": {**info, "best_epoch": 300,
                                     "train_config": {**info["train_config"], "average_from_epoch": 200}}}
    before = {**averaged, "info": {**averaged["info"], "best_epoch": 150}}
    assert "average of every step's weights from epoch 200" in render_model_card(averaged)
    assert "average of every step" not in render_model_card(before)
    assert "average of every step" not in render_model_card(manifest)


def _log(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]


@pytest.mark.slow  # > 10 s on 2 cores
def test_the_average_counts_steps_from_its_epoch_is_what_best_keeps_and_resumes(
        analytic_training_set: Path, tmp_path: Path) -> None:
    dataset = analytic_training_set
    config = TrainConfig(epochs=3, batch_size=4, learning_rate=3e-3, warmup_epochs=1, eval_every=1,
                         checkpoint_every=1, seed=3, average_from_epoch=2)
    whole = tmp_path / "whole"
    train(dataset, whole, model_config=LINEAR_TINY, train_config=config, progress=False)
    checkpoint = torch.load(whole / "checkpoint.pt", weights_only=False)
    steps_per_epoch = checkpoint["step"] // 3
    log = _log(whole)
    assert "averaged_steps" not in log[0]
    assert [r["averaged_steps"] for r in log[1:]] == [steps_per_epoch, 2 * steps_per_epoch]
    average = checkpoint["average"]
    assert int(average["n_averaged"]) == 2 * steps_per_epoch
    live = checkpoint["model"]
    weights = [k for k in live if k.endswith("weight")]
    # The average is not the live model, and the weights kept at an averaged epoch are the average's.
    assert any(not torch.equal(average[f"module.{k}"], live[k]) for k in weights)
    # Stopping after each epoch and resuming (through the start of the average) reproduces the whole run.
    split = tmp_path / "split"
    once = TrainConfig(**{**config.to_dict(), "time_limit_s": 0.0})
    assert train(dataset, split, model_config=LINEAR_TINY, train_config=once, progress=False).epochs_done == 1
    assert train(dataset, split, model_config=LINEAR_TINY, train_config=once, resume=True,
                 progress=False).epochs_done == 2
    average_at = {2: torch.load(split / "checkpoint.pt", weights_only=False)["average"], 3: average}
    train(dataset, split, model_config=LINEAR_TINY, train_config=config, resume=True, progress=False)
    resumed = torch.load(split / "checkpoint.pt", weights_only=False)["average"]
    assert int(resumed["n_averaged"]) == 2 * steps_per_epoch
    for key in weights:
        assert torch.allclose(resumed[f"module.{key}"], average[f"module.{key}"], rtol=1e-5, atol=1e-6), key
    assert [r["val_relae_mapped"] for r in _log(split)] == pytest.approx([r["val_relae_mapped"] for r in log],
                                                                          rel=1e-5)
    # The weights kept as best are the average of their epoch (on this data the average wins from epoch 2).
    best = torch.load(whole / "best.pt", weights_only=False)
    assert best["epoch"] in average_at
    kept = average_at[best["epoch"]]
    for key in weights:
        assert torch.allclose(best["model"][key], kept[f"module.{key}"], rtol=1e-5, atol=1e-6), key
