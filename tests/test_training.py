"""The training loop: logs, checkpoints, resume, determinism, torchrun equivalence (tiny model, CPU)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from brdfcodec.datasets.hdf5 import build_dataset
from brdfcodec.datasets.sources import analytic_sources
from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.models.network import BetaVAE
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.trainer import train

TINY_TRAIN = TrainConfig(epochs=3, batch_size=4, learning_rate=1e-3, warmup_epochs=1, eval_every=1,
                         checkpoint_every=1, seed=7)


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("train-data") / "analytic.h5"
    build_dataset(path, analytic_sources(random_count=5), source_kind="analytic", description="analytic test set",
                  validation_fraction=0.2, seed=0, progress=False)
    return path


def read_log(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "log.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_run_writes_log_checkpoints_and_summary(tiny_dataset: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    result = train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=TINY_TRAIN, progress=False)
    assert result.epochs_done == 3 and result.stop_reason == "completed"
    log = read_log(run)
    assert [r["epoch"] for r in log] == [1, 2, 3]
    for record in log:
        assert len(record["kl_per_dim"]) == TINY_CONFIG.latent_dim
        assert record["val_relae_mapped"] > 0
    assert all(math.isfinite(r["loss"]) and math.isfinite(r["train_relae_mapped"]) for r in log)
    assert {"run.json", "log.jsonl", "checkpoint.pt", "best.pt", "summary.json"} <= {p.name for p in run.iterdir()}
    info = json.loads((run / "run.json").read_text())
    assert len(info["data"]["validation"]) == 2 and info["data"]["source_kind"] == "analytic"
    with pytest.raises(FileExistsError, match="not empty"):
        train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=TINY_TRAIN, progress=False)


@pytest.mark.slow  # > 10 s on 2 cores
def test_resume_continues_exactly(tiny_dataset: Path, tmp_path: Path) -> None:
    straight = tmp_path / "straight"
    train(tiny_dataset, straight, model_config=TINY_CONFIG, train_config=TINY_TRAIN, progress=False)
    split = tmp_path / "split"
    first = TrainConfig(**{**TINY_TRAIN.to_dict(), "time_limit_s": 0.0})
    result = train(tiny_dataset, split, model_config=TINY_CONFIG, train_config=first, progress=False)
    assert result.stop_reason == "time limit" and result.epochs_done == 1
    # A time limit is run control, not part of the recipe: resuming without it is allowed.
    train(tiny_dataset, split, model_config=TINY_CONFIG, train_config=TINY_TRAIN, resume=True, progress=False)
    a, b = read_log(straight), read_log(split)
    assert [r["epoch"] for r in b] == [1, 2, 3]
    for ra, rb in zip(a, b, strict=True):
        assert rb["loss"] == pytest.approx(ra["loss"], rel=1e-5)
        assert rb["val_relae_mapped"] == pytest.approx(ra["val_relae_mapped"], rel=1e-5)


@pytest.mark.slow
def test_resume_after_a_kill_drops_the_log_records_past_the_checkpoint(tiny_dataset: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    first = TrainConfig(**{**TINY_TRAIN.to_dict(), "time_limit_s": 0.0})
    train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=first, progress=False)
    # As if the process had been killed after logging epoch 2 but before its checkpoint.
    with open(run / "log.jsonl", "a", encoding="utf-8") as log:
        log.write(json.dumps({"epoch": 2, "loss": -1.0}) + "\n")
    train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=TINY_TRAIN, resume=True, progress=False)
    log = read_log(run)
    assert [r["epoch"] for r in log] == [1, 2, 3]
    assert all(r["loss"] > 0 for r in log)


@pytest.mark.slow
def test_resume_refuses_a_different_config(tiny_dataset: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=TINY_TRAIN, progress=False)
    other = TrainConfig(**{**TINY_TRAIN.to_dict(), "learning_rate": 5e-4})
    with pytest.raises(ValueError, match="different train config"):
        train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=other, resume=True, progress=False)


@pytest.mark.slow
def test_resume_accepts_a_run_from_before_new_config_fields(tiny_dataset: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    first = TrainConfig(**{**TINY_TRAIN.to_dict(), "time_limit_s": 0.0})
    train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=first, progress=False)
    info = json.loads((run / "run.json").read_text())
    for key in ("weight_decay", "decoder_dropout"):  # as a run.json written before these fields existed
        del info["train_config"][key]
    (run / "run.json").write_text(json.dumps(info))
    result = train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=TINY_TRAIN, resume=True, progress=False)
    assert result.epochs_done == 3
    other = TrainConfig(**{**TINY_TRAIN.to_dict(), "weight_decay": 0.5})
    with pytest.raises(ValueError, match="different train config"):
        train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=other, resume=True, progress=False)


@pytest.mark.slow
def test_two_torchrun_processes_match_one(tiny_dataset: Path, tmp_path: Path) -> None:
    common = ["train", str(tiny_dataset), "--model", "tiny", "--epochs", "2", "--batch-size", "4", "--seed", "7",
              "--eval-every", "1", "--quiet"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    single = subprocess.run([sys.executable, "-m", "brdfcodec", *common, "-o", str(tmp_path / "one")],
                            capture_output=True, text=True, env=env, timeout=600)
    assert single.returncode == 0, single.stderr[-2000:]
    double = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
         "-m", "brdfcodec", *common, "-o", str(tmp_path / "two")],
        capture_output=True, text=True, env=env, timeout=600,
    )
    assert double.returncode == 0, double.stderr[-3000:]
    one, two = read_log(tmp_path / "one"), read_log(tmp_path / "two")
    assert json.loads((tmp_path / "two" / "run.json").read_text())["world_size"] == 2
    for a, b in zip(one, two, strict=True):
        assert b["loss"] == pytest.approx(a["loss"], rel=1e-3)
        assert b["val_relae_mapped"] == pytest.approx(a["val_relae_mapped"], rel=1e-3)


@pytest.mark.slow  # > 10 s on 2 cores
def test_export_card_store_and_registry(tiny_dataset: Path, tmp_path: Path) -> None:
    from brdfcodec.models.registry import ModelNotFoundError, find_model, register_model_folder
    from brdfcodec.models.store import ModelChecksumError, load_model
    from brdfcodec.training.export import export_run

    run = tmp_path / "run"
    config = dataclasses.replace(TINY_CONFIG, linear_basis=True)  # as the shipped model
    train(tiny_dataset, run, model_config=config, train_config=TINY_TRAIN, progress=False)
    folder = tmp_path / "model"
    manifest = export_run(run, folder, name="tiny-test", command="bvae train ...")
    assert {p.name for p in folder.iterdir()} == {"encoder.safetensors", "decoder.safetensors", "model.json",
                                                  "MODEL_CARD.md", "basis.safetensors"}
    from brdfcodec.codec import BrdfDecoder

    basis = BrdfDecoder(folder).shared_basis  # fitted on the training split
    stored = json.loads((folder / "model.json").read_text())
    assert stored["encoder_storage"] == "compact"  # exported encoders are stored compactly (spec/model.md §3)
    assert basis is not None and basis.count == stored["info"]["basis"]["count"]
    # fitted on the training materials in their 6 colour orders: at most 5N − 1 vectors (their rank)
    assert stored["info"]["basis"]["colour_permutations"] is True
    assert basis.count == min(75, 5 * len(stored["info"]["data"]["train"]) - 1)
    card = (folder / "MODEL_CARD.md").read_text()
    for heading in ("## Data", "## Training", "## Reconstruction error", "PCA-8", "## Latent dimensions",
                    "## Known limits", manifest.decoder_sha256):
        assert heading in card
    info = json.loads((folder / "model.json").read_text())["info"]
    assert len(info["errors"]) == 12 and len(info["kl_per_dim"]) == 8 and len(info["traversal"]) == 8
    assert info["summary"]["validation"]["count"] == 2
    encoder, decoder, loaded = load_model(folder)
    assert encoder is not None and decoder is not None and loaded.name == "tiny-test"
    # The exported weights reproduce the run's best model exactly.
    best = torch.load(run / "best.pt", weights_only=False)
    original = BetaVAE(config)
    original.load_state_dict(best["model"])
    original.eval()
    z = torch.randn(2, config.latent_dim)
    with torch.no_grad():
        assert torch.equal(decoder(z), original.decoder(z))
    assert register_model_folder(folder).decoder_sha256 == find_model(manifest.decoder_sha256.upper()).decoder_sha256
    with pytest.raises(ModelNotFoundError, match=manifest.decoder_sha256):
        find_model("0" * 64)
    data = bytearray((folder / "decoder.safetensors").read_bytes())
    data[-1] ^= 0xFF
    (folder / "decoder.safetensors").write_bytes(bytes(data))
    with pytest.raises(ModelChecksumError, match="differs from the manifest"):
        load_model(folder, parts=("decoder",))


@pytest.mark.slow
def test_a_run_can_start_from_an_exported_model(tiny_dataset: Path, tmp_path: Path) -> None:
    from brdfcodec.models.store import export_model, load_model

    torch.manual_seed(123)  # not the run's seed: a fresh model of the run would differ
    folder = tmp_path / "start"
    export_model(BetaVAE(TINY_CONFIG), folder, name="tiny-start", info={})
    # A learning rate of 0: the run's weights are the initial model's, not fresh ones.
    still = TrainConfig(**{**TINY_TRAIN.to_dict(), "epochs": 1, "learning_rate": 1e-30, "min_learning_rate": 0.0})
    run = tmp_path / "run"
    train(tiny_dataset, run, model_config=TINY_CONFIG, train_config=still, progress=False, initial_model=folder)
    best = torch.load(run / "best.pt", weights_only=False)["model"]
    _, decoder, manifest = load_model(folder)
    for key, value in decoder.state_dict().items():
        assert torch.allclose(best[f"decoder.{key}"], value, atol=1e-6), key
    recorded = json.loads((run / "run.json").read_text())["initial_model"]
    assert recorded["name"] == "tiny-start" and recorded["decoder_sha256"] == manifest.decoder_sha256
    other = dataclasses.replace(TINY_CONFIG, latent_dim=TINY_CONFIG.latent_dim + 1)
    with pytest.raises(ValueError, match="configuration differs"):
        train(tiny_dataset, tmp_path / "other", model_config=other, train_config=still, progress=False,
              initial_model=folder)


@pytest.mark.slow
def test_early_stopping_after_patience_evaluations_without_gain(
    tiny_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from brdfcodec.training import evaluation

    monkeypatch.setattr(evaluation.MappedReference, "relae", lambda self, outputs: np.full(len(self.indices), 0.5))
    config = TrainConfig(**{**TINY_TRAIN.to_dict(), "epochs": 10, "patience": 2})
    result = train(tiny_dataset, tmp_path / "run", model_config=TINY_CONFIG, train_config=config, progress=False)
    assert result.stop_reason == "early stopping"
    assert result.epochs_done == 3 and result.best_epoch == 1  # no gain at epochs 2 and 3


def test_weight_decay_shrinks_weights_only() -> None:
    from brdfcodec.training.card import _optimizer_words
    from brdfcodec.training.trainer import _optimizer

    model = BetaVAE(dataclasses.replace(TINY_CONFIG, linear_basis=True))
    assert type(_optimizer(model, TINY_TRAIN)) is torch.optim.Adam
    config = TrainConfig(**{**TINY_TRAIN.to_dict(), "weight_decay": 2.0, "learning_rate": 1e-2})
    optimizer = _optimizer(model, config)
    assert type(optimizer) is torch.optim.AdamW
    before = {name: p.detach().clone() for name, p in model.named_parameters()}
    buffers = {name: b.detach().clone() for name, b in model.named_buffers()}
    for p in model.parameters():
        p.grad = torch.zeros_like(p)  # no gradient: only the decay moves a parameter
    optimizer.step()
    decayed = 0
    for name, p in model.named_parameters():
        expected = before[name] * (1 - 1e-2 * 2.0) if p.ndim >= 2 else before[name]
        torch.testing.assert_close(p.detach(), expected, msg=name)
        decayed += p.ndim >= 2
    assert decayed >= 4
    for name, b in model.named_buffers():
        assert torch.equal(b, buffers[name]), name  # the linear basis is never decayed
    assert _optimizer_words(0.0) == "Adam" and "weight decay 2" in _optimizer_words(2.0)
    for bad in (-1.0, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="weight_decay"):
            TrainConfig(weight_decay=bad)


def test_decoder_dropout_hook_masks_only_in_training() -> None:
    from brdfcodec.training.dropout import DecoderHiddenDropout

    model = BetaVAE(TINY_CONFIG)
    decoder = model.decoder
    z = torch.randn(3, TINY_CONFIG.latent_dim)
    seen: list[torch.Tensor] = []
    decoder.fc[2].register_forward_pre_hook(lambda module, args: seen.append(args[0].detach().clone()))
    dropout = DecoderHiddenDropout(decoder, 0.5)
    keep = torch.zeros(3, TINY_CONFIG.decoder_fc[0], dtype=torch.bool)
    keep[:, ::2] = True
    dropout.set_keep(keep)
    decoder.train()
    decoder(z)
    decoder.eval()
    decoder(z)
    dropped, plain = seen
    torch.testing.assert_close(dropped, plain * keep * 2.0)  # inverted dropout: kept units doubled at p = 0.5
    assert (dropped[:, 1::2] == 0).all() and plain.abs().sum() > 0
    with pytest.raises(ValueError, match="width"):
        dropout.set_keep(torch.ones(3, 5, dtype=torch.bool))
    dropout.remove()
    decoder.train()
    decoder(z)
    torch.testing.assert_close(seen[-1], plain)  # no hook left behind
    with pytest.raises(ValueError, match="decoder_dropout"):
        TrainConfig(decoder_dropout=1.0)


def test_decoder_dropout_draws_leave_the_plain_stream_alone() -> None:
    from brdfcodec.training.trainer import _global_batches

    plain = list(_global_batches(10, TINY_TRAIN, 0, 4))
    config = TrainConfig(**{**TINY_TRAIN.to_dict(), "decoder_dropout": 0.25})
    masked = list(_global_batches(10, config, 0, 4, dropout_width=16))
    assert "keep" not in plain[0] and masked[0]["keep"].shape == (4, 16)
    for key in ("rows", "permutation", "partner", "weight", "noise"):
        assert torch.equal(plain[0][key], masked[0][key]), key
    assert 0.6 < float(torch.cat([d["keep"] for d in masked]).float().mean()) < 0.9


@pytest.mark.slow  # > 10 s on 2 cores
def test_decoder_dropout_run_is_reproducible_and_differs(tiny_dataset: Path, tmp_path: Path) -> None:
    config = TrainConfig(**{**TINY_TRAIN.to_dict(), "epochs": 2, "decoder_dropout": 0.3})
    plain = TrainConfig(**{**TINY_TRAIN.to_dict(), "epochs": 2})
    for name, train_config in (("a", config), ("b", config), ("plain", plain)):
        train(tiny_dataset, tmp_path / name, model_config=TINY_CONFIG, train_config=train_config, progress=False)
    a, b, c = (read_log(tmp_path / name) for name in ("a", "b", "plain"))
    assert [r["loss"] for r in a] == [r["loss"] for r in b]
    assert a[-1]["loss"] != c[-1]["loss"]
    assert json.loads((tmp_path / "a" / "run.json").read_text())["train_config"]["decoder_dropout"] == 0.3


@pytest.mark.slow
def test_epoch_record_is_the_sample_weighted_mean_of_its_steps(tiny_dataset: Path) -> None:
    """The epoch's logged loss, reconstruction, KL and per-dimension KL are means over its samples: each step's
    terms weighted by its batch size (the sums stay on the training device between steps)."""
    from brdfcodec.models.loss import beta_vae_loss, kl_per_dimension
    from brdfcodec.training.augment import mix_physical, permute_colours
    from brdfcodec.training.trainer import _global_batches, _load_training_data, _Progress, _train_epoch, _World

    world = _World(0, 1, torch.device("cpu"))
    data = _load_training_data(tiny_dataset, world, TINY_TRAIN)
    config = dataclasses.replace(TINY_TRAIN, batch_size=2)
    torch.manual_seed(0)
    model = BetaVAE(TINY_CONFIG)
    frozen = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=0.0)  # the model's weights never move
    record = _train_epoch(model, model, frozen, data, TINY_CONFIG, config, 0, world, _Progress())

    model.train()
    totals, kl_dims, count = np.zeros(3), np.zeros(TINY_CONFIG.latent_dim), 0
    with torch.no_grad():
        for draw in _global_batches(len(data.inputs), config, 0, TINY_CONFIG.latent_dim):
            rows, partner = draw["rows"], draw["partner"]
            x = permute_colours(mix_physical(data.inputs[rows], data.inputs[partner], draw["weight"]),
                                draw["permutation"])
            m = permute_colours(data.masks[rows] & data.masks[partner], draw["permutation"])
            recon, mu, logvar = model(x, draw["noise"])
            terms = beta_vae_loss(recon, x, m, mu, logvar, beta=config.beta, recon=config.recon)
            totals += np.array([terms.loss.item(), terms.recon.item(), terms.kl.item()]) * len(rows)
            kl_dims += kl_per_dimension(mu, logvar).sum(0).double().numpy()
            count += len(rows)
    assert count == 2 * (len(data.inputs) // 2)  # every full batch of the epoch
    np.testing.assert_allclose([record["loss"], record["recon"], record["kl"]], totals / count, rtol=1e-5)
    np.testing.assert_allclose(record["kl_per_dim"], kl_dims / count, rtol=1e-5)
    assert record["traversal"] == 0.0


@pytest.mark.slow
def test_folds_and_train_families_choose_the_held_out_materials(tiny_dataset: Path, tmp_path: Path) -> None:
    from brdfcodec.datasets.hdf5 import BrdfDataset
    from brdfcodec.datasets.split import fold_by_family

    with BrdfDataset(tiny_dataset) as dataset:
        names, families = dataset.names, dataset.families
    one_epoch = {**TINY_TRAIN.to_dict(), "epochs": 1}
    held = set()
    for fold in range(2):
        config = TrainConfig(**{**one_epoch, "folds": 2, "fold": fold, "keep": "last"})
        train(tiny_dataset, tmp_path / f"fold{fold}", model_config=TINY_CONFIG, train_config=config, progress=False)
        data = json.loads((tmp_path / f"fold{fold}" / "run.json").read_text())["data"]
        expected = {n for n, f in zip(names, fold_by_family(names, families, folds=2), strict=True) if f == fold}
        assert set(data["validation"]) == expected and not expected & set(data["train"])
        held |= expected
    assert held == set(names)  # every material is held out once
    config = TrainConfig(**{**one_epoch, "all_materials": True, "keep": "last"})  # a release: nothing held out
    train(tiny_dataset, tmp_path / "all", model_config=TINY_CONFIG, train_config=config, progress=False)
    data = json.loads((tmp_path / "all" / "run.json").read_text())["data"]
    assert set(data["train"]) == set(names) and data["validation"] == []
    with pytest.raises(ValueError, match="keep='last' and no folds"):
        TrainConfig(**{**one_epoch, "all_materials": True})  # keep "best" would choose on nothing
    config = TrainConfig(**{**one_epoch, "train_families": "rgl"})
    with pytest.raises(ValueError, match="families the dataset does not hold"):
        train(tiny_dataset, tmp_path / "nofamily", model_config=TINY_CONFIG, train_config=config, progress=False)


@pytest.mark.slow
def test_keep_last_saves_the_last_evaluation(
    tiny_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from brdfcodec.training import trainer

    for keep, kept_epoch in (("last", 3), ("best", 1)):
        errors = iter([0.1, 0.5, 0.9])  # gets worse: "best" keeps epoch 1, "last" epoch 3
        monkeypatch.setattr(trainer, "_evaluate", lambda *args, errors=errors: {"val_relae_mapped": next(errors)})
        config = TrainConfig(**{**TINY_TRAIN.to_dict(), "keep": keep})
        train(tiny_dataset, tmp_path / keep, model_config=TINY_CONFIG, train_config=config, progress=False)
        assert torch.load(tmp_path / keep / "best.pt", weights_only=False)["epoch"] == kept_epoch


@pytest.mark.slow
def test_a_run_with_nothing_held_out_keeps_its_last_weights(tmp_path: Path) -> None:
    path = tmp_path / "all.h5"
    build_dataset(path, analytic_sources(random_count=3), source_kind="analytic", description="all trained",
                  validation_fraction=0.0, progress=False)
    config = TrainConfig(**{**TINY_TRAIN.to_dict(), "epochs": 2})
    result = train(path, tmp_path / "run", model_config=TINY_CONFIG, train_config=config, progress=False)
    assert result.best_epoch == 2
    assert torch.load(tmp_path / "run" / "best.pt", weights_only=False)["epoch"] == 2


@pytest.mark.slow
def test_export_of_a_fold_run_measures_and_fits_on_the_fold_s_training_materials(
    tiny_dataset: Path, tmp_path: Path
) -> None:
    from brdfcodec.training.export import export_run

    config = TrainConfig(**{**TINY_TRAIN.to_dict(), "epochs": 1, "folds": 3, "fold": 1, "keep": "last"})
    train(tiny_dataset, tmp_path / "run", model_config=dataclasses.replace(TINY_CONFIG, linear_basis=True),
          train_config=config, progress=False)
    run_data = json.loads((tmp_path / "run" / "run.json").read_text())["data"]
    export_run(tmp_path / "run", tmp_path / "model", name="fold-test", basis_count=5)
    info = json.loads((tmp_path / "model" / "model.json").read_text())["info"]
    assert info["data"]["train"] == run_data["train"] and info["data"]["validation"] == run_data["validation"]
    assert info["summary"]["validation"]["count"] == len(run_data["validation"])
    assert info["basis"]["materials"] == len(run_data["train"])
