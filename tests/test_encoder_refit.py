"""Refitting an exported model's encoder to its frozen decoder (issue 50: codes at effort 0 no worse than the default
model's): the decoder and every file stay valid, the codes get better, held-out materials stay held out."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.models.network import BetaVAE
from brdfcodec.training.encoder_refit import RefitConfig, refit_encoder


def _tiny_model(seed: int) -> BetaVAE:
    torch.manual_seed(seed)
    model = BetaVAE(dataclasses.replace(TINY_CONFIG, linear_basis=True)).eval()
    with torch.no_grad():  # a non-trivial decoder, so that codes matter
        model.decoder.basis_mean.uniform_(0.2, 1.5)
        model.decoder.basis_components.normal_(0.0, 0.05)
        model.decoder.upsample[-1].bias.normal_(0.0, 0.1)
    return model


def _mean_error(model: BetaVAE, x: torch.Tensor) -> float:
    with torch.no_grad():
        mu, _ = model.encoder(x)
        return float((model.decoder(mu) - x).abs().mean())


@pytest.mark.slow
def test_a_refit_lowers_the_error_of_the_codes_and_leaves_the_decoder_alone() -> None:
    model = _tiny_model(3)
    with torch.no_grad():  # materials the decoder makes exactly, from codes the encoder does not give
        x = model.decoder(3.0 * torch.randn(8, model.config.latent_dim))
    masks = torch.ones_like(x, dtype=torch.bool)
    decoder_before = {k: v.clone() for k, v in model.decoder.state_dict().items()}
    linear_path_before = model.encoder.basis_projection.clone(), model.encoder.basis_mean.clone()
    before = _mean_error(model, x)
    result = refit_encoder(model.encoder, model.decoder, x, masks,
                           RefitConfig(epochs=20, batch_size=4, analytic_materials=0, learning_rate=3e-3,
                                       mix_probability=0.0, colour_permutations=False))
    after = _mean_error(model, x)
    assert after < 0.5 * before, (before, after)
    assert len(result.epoch_losses) == 20 and result.epoch_losses[-1] < result.epoch_losses[0]
    for key, value in model.decoder.state_dict().items():
        assert torch.equal(value, decoder_before[key]), key
    assert torch.equal(model.encoder.basis_projection, linear_path_before[0])  # derived from the decoder's basis
    assert torch.equal(model.encoder.basis_mean, linear_path_before[1])
    assert not model.encoder.training and not any(p.requires_grad for p in model.encoder.parameters())
    assert all(p.requires_grad for p in model.decoder.parameters())  # as it was given


@pytest.mark.slow
def test_the_free_dimension_weight_frees_the_dimensions_beyond_the_factors() -> None:
    """Analytic materials whose best codes lie off 0 beyond their 2 factors: with the training's hold (weight 1)
    their μ stays near 0 there, freed (0) it moves towards the codes that make them, the factor dimensions held
    on their targets either way."""
    from brdfcodec.training.factor_supervision import FactorPool

    dim = TINY_CONFIG.latent_dim
    codes = 2.0 * torch.randn(8, dim, generator=torch.Generator().manual_seed(5))
    free: dict[float, torch.Tensor] = {}
    for weight in (1.0, 0.0):
        model = _tiny_model(3)
        with torch.no_grad():
            x = model.decoder(codes)
        masks = torch.ones_like(x, dtype=torch.bool)
        targets = torch.zeros_like(codes)
        targets[:, :2] = codes[:, :2]
        pool = FactorPool(x, masks, targets, torch.ones_like(codes), seed=0, factor_count=2)
        valid = float(masks[0].sum())
        refit_encoder(model.encoder, model.decoder, x, masks,
                      RefitConfig(epochs=30, batch_size=4, analytic_materials=8, analytic_batch=4, learning_rate=3e-3,
                                  mix_probability=0.0, colour_permutations=False, factor_weight=0.3 * valid,
                                  free_dimension_weight=weight), analytic=pool)
        with torch.no_grad():
            mu, _ = model.encoder(x)
        assert float((mu[:, :2] - codes[:, :2]).abs().mean()) < 0.5, weight  # the factors held either way
        free[weight] = (mu[:, 2:] - codes[:, 2:]).abs().mean()
    assert float(free[0.0]) < 0.7 * float(free[1.0]), free


def test_refit_settings_are_checked() -> None:
    for bad in ({"epochs": 0}, {"learning_rate": 0.0}, {"mix_probability": 1.5}, {"analytic_materials": -1},
                {"logvar_weight": -1.0}, {"analytic_batch": 0}, {"free_dimension_weight": -0.1},
                {"free_dimension_weight": 1.5}, {"free_dimension_weight": math.nan},
                {"free_dimension_weight": 0.0},  # the factor supervision it scales is off (factor_weight 0)
                {"free_dimension_weight": 0.5, "factor_weight": 1.0, "analytic_materials": 0}):
        with pytest.raises(ValueError):
            RefitConfig(**bad)
    assert RefitConfig(free_dimension_weight=0.0, factor_weight=1.0).free_dimension_weight == 0.0


def test_the_cli_defaults_are_the_library_s() -> None:
    from brdfcodec.cli.model_command import RefitDefaults

    config = RefitConfig()
    for field in ("epochs", "analytic_materials", "learning_rate", "logvar_weight", "mix_probability",
                  "analytic_batch", "free_dimension_weight", "seed"):
        assert getattr(RefitDefaults, field) == getattr(config, field), field


@pytest.fixture(scope="module")
def exported_fold_model(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A tiny run on 6 analytic materials with fold 1 of 3 held out, exported (dataset, model folder)."""
    from brdfcodec.datasets.hdf5 import build_dataset
    from brdfcodec.datasets.sources import analytic_sources
    from brdfcodec.training.config import TrainConfig
    from brdfcodec.training.export import export_run
    from brdfcodec.training.trainer import train

    root = tmp_path_factory.mktemp("refit")
    dataset = root / "analytic.h5"
    build_dataset(dataset, analytic_sources(random_count=6), source_kind="analytic", description="refit test set",
                  validation_fraction=0.2, seed=0, progress=False)
    config = TrainConfig(epochs=1, batch_size=2, learning_rate=1e-3, warmup_epochs=1, eval_every=1,
                         checkpoint_every=1, seed=7, folds=3, fold=1, keep="last")
    train(dataset, root / "run", model_config=dataclasses.replace(TINY_CONFIG, linear_basis=True),
          train_config=config, progress=False)
    export_run(root / "run", root / "model", name="refit-test", basis_count=3)
    return dataset, root / "model"


@pytest.mark.slow
def test_a_refitted_folder_keeps_its_decoder_and_is_remeasured(exported_fold_model, tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    from brdfcodec.models.store import load_model
    from brdfcodec.training import encoder_refit

    dataset, folder = exported_fold_model
    seen: list[int] = []
    real = encoder_refit.refit_encoder

    def spy(encoder, decoder, inputs, masks, config, **kwargs):  # noqa: ANN001, ANN202
        seen.append(len(inputs))
        return real(encoder, decoder, inputs, masks, config, **kwargs)

    monkeypatch.setattr(encoder_refit, "refit_encoder", spy)
    out = tmp_path / "refitted"
    config = RefitConfig(epochs=2, batch_size=2, analytic_materials=2, analytic_batch=2, learning_rate=1e-2,
                         factor_weight=100.0)
    manifest = encoder_refit.refit_model_folder(folder, dataset, config, output=out, name="refit-test-2",
                                                command="bvae model ...")
    before = json.loads((folder / "model.json").read_text())
    after = json.loads((out / "model.json").read_text())
    assert seen == [len(before["info"]["data"]["train"])]  # the model's training materials, never its held-out
    assert (out / "decoder.safetensors").read_bytes() == (folder / "decoder.safetensors").read_bytes()
    assert (out / "basis.safetensors").read_bytes() == (folder / "basis.safetensors").read_bytes()
    assert manifest.decoder_sha256 == before["decoder_sha256"]
    assert after["encoder_sha256"] != before["encoder_sha256"] and after["encoder_storage"] == "compact"
    load_model(out)  # verified: every hash matches
    refit = after["info"]["encoder_refit"]
    assert refit["config"]["epochs"] == 2 and refit["config"]["factor_weight"] == 100.0
    assert len(refit["epoch_losses"]) == 2 and all(math.isfinite(v) for v in refit["epoch_losses"])
    assert refit["original_encoder_sha256"] == before["encoder_sha256"] and refit["original_name"] == "refit-test"
    assert after["name"] == manifest.name == "refit-test-2"
    # the encoder's measurements are made again: the stored errors are the new encoder's
    assert after["info"]["errors"] != before["info"]["errors"]
    assert after["info"]["summary"]["validation"]["count"] == len(before["info"]["data"]["validation"])
    assert "Encoder refitted after export" in (out / "MODEL_CARD.md").read_text(encoding="utf-8")
    assert "encoder_refit" not in before["info"]  # the source folder is untouched


@pytest.mark.slow
def test_the_cli_refuses_an_existing_output_and_a_dataset_without_the_training_materials(
    exported_fold_model, tmp_path: Path
) -> None:
    from brdfcodec.datasets.hdf5 import build_dataset
    from brdfcodec.datasets.sources import analytic_sources

    dataset, folder = exported_fold_model
    taken = tmp_path / "taken"
    taken.mkdir()
    command = [sys.executable, "-m", "brdfcodec", "model", "refit-encoder", str(folder), "--dataset", str(dataset),
               "-o", str(taken), "--epochs", "1", "--analytic-materials", "0"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert str(taken) in done.stderr and not any(taken.iterdir())
    other = tmp_path / "other.h5"
    build_dataset(other, analytic_sources(random_count=2), source_kind="analytic", description="other",
                  validation_fraction=0.5, seed=5, progress=False)
    copy = tmp_path / "model"
    shutil.copytree(folder, copy)
    original = (copy / "model.json").read_bytes()
    done = subprocess.run(command[:5] + [str(copy), "--dataset", str(other), "--epochs", "1"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "lacks materials the model trained on" in done.stderr and str(other) in done.stderr
    assert (copy / "model.json").read_bytes() == original  # nothing rewritten
    fresh = tmp_path / "fresh"  # a model trained without factor terms: the weight on them cannot act
    done = subprocess.run(command[:8] + ["-o", str(fresh), "--epochs", "1", "--free-dimension-weight", "0"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "free_dimension_weight 0" in done.stderr and "no effect" in done.stderr and not fresh.exists()


@pytest.mark.slow
def test_a_refit_in_place_replaces_the_folder_whole_or_not_at_all(exported_fold_model, tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Without -o the folder is rewritten: a crash once the new encoder file is written and before model.json
    names it leaves the old folder, whole and verified; a refit that finishes leaves the new one, nothing beside."""
    from brdfcodec.models.store import load_model
    from brdfcodec.training import encoder_refit

    dataset, source = exported_fold_model
    folder = tmp_path / "model"
    shutil.copytree(source, folder)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    config = RefitConfig(epochs=1, batch_size=2, analytic_materials=0, learning_rate=1e-2)
    real_card = encoder_refit.write_card

    def crash(target, stored):  # noqa: ANN001, ANN202
        assert (target / "encoder.safetensors").read_bytes() != before["encoder.safetensors"]  # written already
        raise KeyboardInterrupt

    monkeypatch.setattr(encoder_refit, "write_card", crash)
    with pytest.raises(KeyboardInterrupt):
        encoder_refit.refit_model_folder(folder, dataset, config)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]
    monkeypatch.setattr(encoder_refit, "write_card", real_card)
    manifest = encoder_refit.refit_model_folder(folder, dataset, config)
    assert manifest.folder == folder and manifest.encoder_sha256 != json.loads(before["model.json"])["encoder_sha256"]
    load_model(folder)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]
