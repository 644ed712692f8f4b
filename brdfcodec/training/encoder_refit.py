"""Refit an exported model's encoder to its frozen decoder: codes at effort 0 as good as the decoder allows.

A β-VAE's encoder is trained together with its decoder under prior terms (β·KL, the latent's rate, factor
supervision) that shape the latent space; its μ is then not the code the decoder reconstructs a material best from,
and the codec's refinement (``spec/bvae-format.md`` §5, effort ≥ 1) recovers part of the difference with a few
gradient steps per material. Refitting trains the encoder alone, the decoder frozen, to minimise the same
reconstruction error the refinement minimises, on the model's own training materials (colour-permuted and blended,
as in training) and on analytic materials drawn fresh: the amortisation gap closed once, for every material, at
training time. The decoder, its hash and every file made with the model are unchanged; only the codes an encoder
gives change.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import save_file

from brdfcodec.codec import BrdfDecoder
from brdfcodec.datasets.analytic import FACTOR_ALPHA_RANGE
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.io.atomic import atomic_folder, atomic_output
from brdfcodec.models.network import BetaVAE, Decoder, Encoder
from brdfcodec.models.parameters import describe_parameters
from brdfcodec.models.store import (ENCODER_FILE, MANIFEST, ModelManifest, compact_encoder_tensors,
                                    load_manifest, load_model, sha256_of_file, write_manifest)
from brdfcodec.training.alignment import align_to_factors
from brdfcodec.training.augment import COLOUR_PERMUTATIONS, mix_physical, permute_colours
from brdfcodec.training.export import comparison_row, trained_rows, write_card
from brdfcodec.training.factor_supervision import FactorPool, build_factor_pool
from brdfcodec.training.measurements import kl_per_dim, measure_model, summarise, traversal_changes

__all__ = ["RefitConfig", "RefitResult", "refit_encoder", "refit_model_folder"]


@dataclass(frozen=True)
class RefitConfig:
    """How an encoder is refitted (``bvae model refit-encoder``).

    Attributes
    ----------
    epochs : int
        Passes over the training materials, ≥ 1.
    batch_size : int
        Training materials per step (each blended and colour-permuted), ≥ 1.
    analytic_materials : int
        Analytic materials drawn for the refit (:func:`~brdfcodec.datasets.analytic.sample_factor_materials`);
        0 refits on the training materials alone.
    analytic_batch : int
        Analytic materials added to each step's batch (when there are any), ≥ 1; as many as the real ones, as the
        release recipe trains with (``factor_batch``): with 2 a step the factor terms do not hold the benchmark's
        MIG (``reports/disentanglement/encoder-refit-fold2.txt``).
    learning_rate : float
        Adam's step size, > 0.
    mix_probability : float
        Chance that a training material is blended with another (in reflectance), in [0, 1].
    colour_permutations : bool
        Permute each training material's colour channels at random.
    logvar_weight : float
        Weight of the squared difference between the new and the original encoder's log σ², ≥ 0: σ keeps its
        meaning (the codes' spread a record may store) while μ moves.
    factor_weight : float
        Weight of the factor supervision of the analytic materials' μ (:func:`~brdfcodec.training.factor_supervision.
        factor_supervision_loss`), ≥ 0, in the units of training (against each material's L1 summed over its valid
        entries): a supervised model's own weight keeps its encoder's μ of analytic materials on their factors (the
        disentanglement benchmark scores that μ) while the reconstruction moves the other materials' codes; 0 leaves
        the analytic materials to the reconstruction alone.
    free_dimension_weight : float
        Factor on that term's dimensions beyond the analytic family's factors, in [0, 1]: training holds the
        analytic materials' μ at 0 there (weight 1); 0 frees those dimensions for the analytic materials'
        reconstruction at effort 0 while their factor dimensions stay held. A value other than 1 needs the
        factor supervision on (``factor_weight`` > 0 and ``analytic_materials`` > 0).
    seed : int
        Seed of the draws (batches, blends, permutations, analytic materials).
    """

    epochs: int = 60
    batch_size: int = 8
    analytic_materials: int = 256
    analytic_batch: int = 8
    learning_rate: float = 1e-4
    mix_probability: float = 0.25
    colour_permutations: bool = True
    logvar_weight: float = 1e-3
    factor_weight: float = 0.0
    free_dimension_weight: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1 or self.analytic_batch < 1 or self.analytic_materials < 0:
            raise ValueError(f"epochs, batch_size and analytic_batch must be ≥ 1 and analytic_materials ≥ 0, "
                             f"got {self}")
        if not self.learning_rate > 0 or not 0 <= self.mix_probability <= 1 or not self.logvar_weight >= 0 \
                or not self.factor_weight >= 0 or not 0 <= self.free_dimension_weight <= 1:
            raise ValueError(f"learning_rate must be > 0, mix_probability and free_dimension_weight in [0, 1], "
                             f"logvar_weight and factor_weight ≥ 0, got {self}")
        if self.free_dimension_weight != 1.0 and (self.factor_weight == 0 or self.analytic_materials == 0):
            raise ValueError(f"free_dimension_weight {self.free_dimension_weight:g} scales the factor supervision, "
                             f"which is off (factor_weight {self.factor_weight:g}, analytic_materials "
                             f"{self.analytic_materials}): it would have no effect")


@dataclass(frozen=True)
class RefitResult:
    """What a refit did: the mean reconstruction loss (masked L1 of mapped values per valid entry) of each epoch,
    of the training materials as augmented, and the seconds it took."""

    epoch_losses: tuple[float, ...]
    seconds: float


def _masked_l1(decoded: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per material, the mean absolute mapped error over its valid entries, ``(B,)``."""
    weight = mask.to(decoded.dtype)
    return ((decoded - target).abs() * weight).flatten(1).sum(1) / weight.flatten(1).sum(1).clamp_min(1.0)


def refit_encoder(encoder: Encoder, decoder: Decoder, inputs: torch.Tensor, masks: torch.Tensor,
                  config: RefitConfig, *, analytic: FactorPool | None = None,
                  log: Path | None = None) -> RefitResult:
    """Train ``encoder`` (in place) so that ``decoder(encoder(x).μ)`` reconstructs ``x``, the decoder frozen.

    The encoder is left in evaluation mode with no parameter requiring gradients; the decoder as it was given.

    Parameters
    ----------
    encoder : Encoder
        Trained encoder; its linear path (derived from the decoder's basis) stays as it is.
    decoder : Decoder
        The model's decoder; not changed.
    inputs, masks : Tensor, shape (N, 63, 90, 90)
        Mapped kept slices of the training materials (float32) and their valid entries (bool).
    config : RefitConfig
    analytic : FactorPool, optional
        Analytic materials (inputs, masks, factor targets and weights), ``config.analytic_batch`` of them drawn
        each step.
    log : Path, optional
        A JSON line per epoch is appended to this file (epoch, loss, seconds).

    Returns
    -------
    RefitResult
    """
    if len(inputs) == 0:
        raise ValueError("a refit needs at least one training material")
    generator = torch.Generator().manual_seed(config.seed)
    original = copy.deepcopy(encoder).eval()
    decoder_flags = [p.requires_grad for p in decoder.parameters()]
    for module in (original, decoder):
        for parameter in module.parameters():
            parameter.requires_grad_(False)
    decoder.eval()
    encoder.train()
    trainable = [p for p in encoder.parameters() if p.is_floating_point()]
    for parameter in trainable:
        parameter.requires_grad_(True)
    optimiser = torch.optim.Adam(trainable, lr=config.learning_rate)
    if analytic is not None:  # the dimensions beyond the family's factors, held at 0 by training, weighted
        factor_weights = analytic.weights.clone()
        factor_weights[:, analytic.factor_count :] *= config.free_dimension_weight
    n = len(inputs)
    steps = max(1, n // config.batch_size)
    losses: list[float] = []
    start = time.perf_counter()
    for epoch in range(config.epochs):
        epoch_start = time.perf_counter()
        order = torch.randperm(n, generator=generator)
        total = 0.0
        for step in range(steps):
            rows = order[step * config.batch_size : (step + 1) * config.batch_size]
            partner = torch.randint(n, (len(rows),), generator=generator)
            blend = torch.rand(len(rows), generator=generator) < config.mix_probability
            weight = torch.where(blend, torch.rand(len(rows), generator=generator), torch.ones(len(rows)))
            permutation = (torch.randint(len(COLOUR_PERMUTATIONS), (len(rows),), generator=generator)
                           if config.colour_permutations else torch.zeros(len(rows), dtype=torch.long))
            x = permute_colours(mix_physical(inputs[rows], inputs[partner], weight), permutation)
            m = permute_colours(masks[rows] & (masks[partner] | ~blend.view(-1, 1, 1, 1)), permutation)
            if analytic is not None:
                picks = torch.randint(len(analytic), (config.analytic_batch,), generator=generator)
                x, m = torch.cat([x, analytic.inputs[picks]]), torch.cat([m, analytic.masks[picks]])
            mu, logvar = encoder(x)
            with torch.no_grad():
                _, logvar_before = original(x)
            reconstruction = _masked_l1(decoder.unbounded(mu), x, m)
            loss = reconstruction.mean() + config.logvar_weight * (logvar - logvar_before).pow(2).mean()
            if analytic is not None and config.factor_weight > 0:
                # training's balance: the factor term against the L1 summed over the material's valid entries
                valid = m[len(rows):].flatten(1).sum(1).clamp_min(1).to(mu.dtype)
                squared = ((mu[len(rows):] - analytic.targets[picks]).pow(2) * factor_weights[picks]).sum(1)
                loss = loss + config.factor_weight * (squared / valid).sum() / len(x)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            total += float(reconstruction[: len(rows)].detach().mean())
        losses.append(total / steps)
        if log is not None:
            with log.open("a", encoding="utf-8") as out:
                out.write(json.dumps({"epoch": epoch + 1, "loss": losses[-1],
                                      "seconds": time.perf_counter() - epoch_start}) + "\n")
    encoder.eval()
    for parameter in trainable:
        parameter.requires_grad_(False)
    for parameter, flag in zip(decoder.parameters(), decoder_flags, strict=True):
        parameter.requires_grad_(flag)
    return RefitResult(tuple(losses), time.perf_counter() - start)


def _write_encoder(encoder: Encoder, name: str, manifest: ModelManifest, folder: Path) -> None:
    """``encoder.safetensors`` in the storage the manifest names (atomically)."""
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in encoder.state_dict().items()}
    metadata = {"brdfcodec_model": name, "config": manifest.config.to_json(), "part": "encoder"}
    if manifest.encoder_storage == "compact":
        tensors, metadata = compact_encoder_tensors(tensors), {**metadata, "storage": "compact"}
    with atomic_output(folder / ENCODER_FILE, overwrite=True) as tmp:
        save_file(tensors, str(tmp), metadata=metadata)
    os.chmod(folder / ENCODER_FILE, 0o644)


def _remeasured(stored: dict[str, Any], encoder: Encoder, decoder: Decoder, dataset: BrdfDataset,
                train_rows: list[int]) -> None:
    """Rewrite the manifest's measurements that depend on the encoder (errors, KL, latent spread, traversals,
    the factor alignment's correlations and the named parameters), as ``bvae model export`` measures them."""
    info = stored["info"]
    latent_dim = encoder.config.latent_dim
    measured = measure_model(encoder, decoder, dataset, latent_dim, train_rows)
    mu, logvar = measured.mu[train_rows], measured.logvar[train_rows]
    info["errors"] = [row.as_dict() for row in measured.errors]
    info["summary"] = summarise(measured.errors)
    info["kl_per_dim"] = kl_per_dim(mu, logvar)
    info["latent_mean"], info["latent_std"] = mu.mean(0).tolist(), mu.std(0).tolist()
    info["traversal"] = traversal_changes(decoder, mu.mean(0), np.maximum(mu.std(0), 1e-6))
    factors: list[tuple[str, float]] = []
    if isinstance(info.get("alignment"), dict):
        model = BetaVAE(encoder.config)
        model.encoder, model.decoder = encoder, decoder
        before = info["alignment"]
        alignment = align_to_factors(model, materials=int(before["materials"]), seed=int(before["seed"]),
                                     rotate=False)
        info["alignment"] = {**alignment.as_dict(), "rotation": before["rotation"]}  # the export's, kept
        factors = list(zip(alignment.factor_names, alignment.correlation, strict=True))
    stored["parameters"] = describe_parameters(BrdfDecoder.from_network(decoder), factors=factors)
    if info.get("comparisons"):
        info["comparisons"][0] = {**comparison_row("this model", info, None),
                                  "decoder_bytes": info["comparisons"][0].get("decoder_bytes")}


def refit_model_folder(folder: str | os.PathLike[str], dataset_path: str | os.PathLike[str], config: RefitConfig, *,
                       output: str | os.PathLike[str] | None = None, name: str | None = None, command: str = "",
                       log: str | os.PathLike[str] | None = None) -> ModelManifest:
    """Refit a model folder's encoder (:func:`refit_encoder`) and store it with remeasured measurements.

    Parameters
    ----------
    folder : str or os.PathLike
        An exported model folder.
    dataset_path : str or os.PathLike
        A dataset holding every material the model trained on (``model.json``'s ``info.data.train``); the refit
        trains on those alone, so that a model's held-out materials stay held out.
    config : RefitConfig
    output : str or os.PathLike, optional
        A new folder for the refitted model (a copy of ``folder`` with the new encoder; it must not exist). By
        default ``folder`` itself is replaced, as a whole, by the refitted folder (:func:`~brdfcodec.io.atomic.
        atomic_folder`: a reader sees the old model or the new one).
    name : str, optional
        A new name for the refitted model (``model.json``'s ``name``; the decoder file keeps the name it was
        written with, which its hash covers). By default the model keeps its name.
    command : str
        The command, stored in ``info.encoder_refit``.
    log : str or os.PathLike, optional
        Progress, a JSON line per epoch.

    Returns
    -------
    ModelManifest
        The refitted model's; its decoder hash is the original's.

    Raises
    ------
    ValueError
        The dataset lacks some of the model's training materials, or the model has no training list.
    FileExistsError
        ``output`` exists.
    """
    source = Path(folder)
    if output is not None and Path(output).exists():
        raise FileExistsError(f"{output}: exists; a refit writes a new folder")
    encoder, decoder, manifest = load_model(source)
    assert encoder is not None and decoder is not None
    stored = json.loads((source / MANIFEST).read_text(encoding="utf-8"))
    info = stored.setdefault("info", {})
    trained = info.get("data", {}).get("train") if isinstance(info.get("data"), dict) else None
    if not isinstance(trained, list) or not trained:
        raise ValueError(f"{source / MANIFEST}: info.data.train does not list the materials the model trained on")
    with BrdfDataset(dataset_path) as dataset:
        rows = trained_rows(dataset, info)
        if len(rows) != len(trained) or any(dataset.names[i] not in set(trained) for i in rows):
            missing = sorted(set(trained) - set(dataset.names))[:5]
            raise ValueError(f"{dataset_path}: the dataset lacks materials the model trained on, e.g. {missing}")
        inputs = torch.from_numpy(dataset.inputs(rows))
        masks = torch.from_numpy(dataset.input_masks(rows))
        analytic = None
        if config.analytic_materials:
            trained_with = info.get("train_config", {}) if isinstance(info.get("train_config"), dict) else {}
            if config.factor_weight > 0 and encoder.config.latent_dim < 7:
                raise ValueError(f"{source}: factor supervision needs a latent of at least 7 dimensions")
            saturation = bool(trained_with.get("factor_saturation", True)) and encoder.config.latent_dim >= 8
            analytic = build_factor_pool(config.analytic_materials, config.seed + 1, max(7, encoder.config.latent_dim),
                                         saturation=saturation,
                                         alpha_min=float(trained_with.get("factor_alpha_min", FACTOR_ALPHA_RANGE[0])))
        result = refit_encoder(encoder, decoder, inputs, masks, config, analytic=analytic,
                               log=Path(log) if log is not None else None)
        del inputs, masks, analytic
        _remeasured(stored, encoder, decoder, dataset, rows)
    info["encoder_refit"] = {"config": asdict(config), "dataset": str(dataset_path), "command": command,
                             "seconds": result.seconds, "epoch_losses": list(result.epoch_losses),
                             "original_encoder_sha256": manifest.encoder_sha256, "original_name": manifest.name}
    if name is not None:
        stored["name"] = name
    target = source if output is None else Path(output)
    # The whole folder at once: a new one appears complete, an old one is replaced as a whole (never an encoder
    # file whose hash model.json does not name yet).
    with atomic_folder(target, replace=output is None) as staging:
        if output is not None:
            shutil.copytree(source, staging, symlinks=True, dirs_exist_ok=True,
                            ignore=shutil.ignore_patterns(MANIFEST))
            os.chmod(staging, 0o700)  # copytree gave it the source's mode; the new folder's is set when it appears
        _write_encoder(encoder, stored["name"], manifest, staging)
        stored["encoder_sha256"] = sha256_of_file(staging / ENCODER_FILE)
        info["encoder_bytes"] = (staging / ENCODER_FILE).stat().st_size
        write_card(staging, stored)
        write_manifest(staging, stored)
    return load_manifest(target)

