"""Training with a second reconstruction term at μ itself (``TrainConfig.mean_recon_weight``, issue 50: the codes an
encoder gives, what ``bvae model evaluate`` decodes at effort 0, are codes the decoder is trained on)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.models.loss import beta_vae_loss, masked_recon_per_sample
from brdfcodec.models.store import load_model
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.export import export_run
from brdfcodec.training.trainer import train


def test_the_weight_is_checked() -> None:
    for bad in (-1.0, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="mean_recon_weight"):
            TrainConfig(mean_recon_weight=bad)
    with pytest.raises(ValueError, match="decoder_dropout"):
        TrainConfig(mean_recon_weight=1.0, decoder_dropout=0.1)
    assert TrainConfig.from_dict(json.loads(json.dumps({"mean_recon_weight": 2.0}))).mean_recon_weight == 2.0


def test_the_per_material_error_is_the_beta_vae_s_own() -> None:
    generator = torch.Generator().manual_seed(0)
    x, y = torch.rand(3, 63, 90, 90, generator=generator), torch.rand(3, 63, 90, 90, generator=generator)
    mask = torch.rand(3, 63, 90, 90, generator=generator) > 0.3
    mu, logvar = torch.zeros(3, 8), torch.zeros(3, 8)
    for kind in ("l1", "l2"):
        per = masked_recon_per_sample(x, y, mask, kind)
        assert per.shape == (3,)
        assert torch.allclose(per.mean(), beta_vae_loss(x, y, mask, mu, logvar, beta=12.0, recon=kind).recon)
        assert torch.allclose(per[0], ((x[0] - y[0]).abs() if kind == "l1" else (x[0] - y[0]) ** 2)[mask[0]].sum())


@pytest.mark.slow  # about a minute on 2 cores
def test_a_run_with_the_term_decodes_its_codes_better(analytic_training_set: Path, tmp_path: Path) -> None:
    """The same draws, a β so heavy that the sampled codes carry little: with the term, the decoder of μ itself
    reconstructs the training materials better, and the run's configuration says so."""
    base = dict(epochs=8, batch_size=4, learning_rate=3e-3, warmup_epochs=1, eval_every=4, checkpoint_every=4,
                seed=7, keep="last", beta=200.0)
    errors = {}
    for label, weight in {"plain": 0.0, "at-mean": 3.0}.items():
        train(analytic_training_set, tmp_path / label, model_config=TINY_CONFIG,
              train_config=TrainConfig(**base, mean_recon_weight=weight), progress=False)
        export_run(tmp_path / label, tmp_path / f"{label}-model", name=label, basis_count=0)
        encoder, decoder, _ = load_model(tmp_path / f"{label}-model")
        with BrdfDataset(analytic_training_set) as dataset:
            rows = [i for i, split in enumerate(dataset.split) if split == "train"]
            x = torch.from_numpy(dataset.inputs(rows))
            m = torch.from_numpy(dataset.input_masks(rows))
        with torch.no_grad():
            mu, _ = encoder(x)
            errors[label] = float(masked_recon_per_sample(decoder.unbounded(mu), x, m, "l1").mean())
    assert errors["at-mean"] < 0.95 * errors["plain"], errors  # 0.91 measured: 16 steps of a tiny model
    stored = json.loads((tmp_path / "at-mean" / "run.json").read_text())["train_config"]
    assert TrainConfig.from_dict(stored).mean_recon_weight == 3.0
