"""The training loop: one process on CPU or GPU, or many under ``torchrun``.

A run directory holds ``run.json`` (configs, dataset, world size),
``log.jsonl`` (one JSON object per epoch), ``checkpoint.pt`` (everything
needed to resume), ``best.pt`` (weights with the best validation RelAE: the
running average of the weights once ``TrainConfig.average_from_epoch`` is
reached) and ``summary.json`` at the end.

Reproducibility across process counts: every random draw of a step (batch
order, augmentation, reparameterisation noise) is made for the *global*
batch from a generator seeded by (seed, epoch) and identical on every rank;
each rank takes its slice. With GroupNorm (per-sample) the gradients
averaged by DistributedDataParallel then equal those of one process with the
same global batch.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel
from torch.optim.swa_utils import AveragedModel
from tqdm.auto import tqdm

from brdfcodec.conventions import NETWORK_INPUT_SHAPE
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.datasets.split import VALIDATION, fold_by_family
from brdfcodec.errors import DatasetError
from brdfcodec.io.atomic import atomic_output
from brdfcodec.models.config import ModelConfig
from brdfcodec.models.loss import beta_vae_loss, kl_per_dimension, latent_rate, masked_recon_per_sample
from brdfcodec.models.network import BetaVAE, initialise_linear_basis, linear_path_trainable
from brdfcodec.models.store import load_model
from brdfcodec.representation.edge_slots import edge_slot_targets
from brdfcodec.training.augment import COLOUR_PERMUTATIONS, mix_physical, permute_colours
from brdfcodec.training.checkpoint import load_checkpoint
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.dropout import DecoderHiddenDropout
from brdfcodec.training.evaluation import MappedReference, reconstruct_mapped
from brdfcodec.training.factor_supervision import FactorPool, build_factor_pool, factor_supervision_loss
from brdfcodec.training.traversal import TraversalPenalty, traversed_codes
from brdfcodec.version import __version__

__all__ = ["TrainResult", "train"]

CHECKPOINT = "checkpoint.pt"
BEST = "best.pt"
LOG = "log.jsonl"
_RUN_CONTROL = {"time_limit_s", "checkpoint_every"}


@dataclass(frozen=True)
class TrainResult:
    """Outcome of :func:`train` (on rank 0; other ranks get the same epochs and reason)."""

    run_dir: Path
    epochs_done: int
    best_epoch: int
    best_validation_relae: float
    stop_reason: str
    seconds: float


@dataclass(frozen=True)
class _World:
    rank: int
    size: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def _setup_world() -> _World:
    size = int(os.environ.get("WORLD_SIZE", "1"))
    if size > 1 and not dist.is_initialized():
        dist.init_process_group(backend="nccl" if torch.cuda.is_available() else "gloo")
    rank = dist.get_rank() if size > 1 else 0
    if torch.cuda.is_available():
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    else:
        device = torch.device("cpu")
    return _World(rank, size, device)


def _learning_rate(step: int, steps_per_epoch: int, config: TrainConfig) -> float:
    warmup = config.warmup_epochs * steps_per_epoch
    total = config.epochs * steps_per_epoch
    if step < warmup:
        return config.learning_rate * (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, total - warmup))
    return config.min_learning_rate + 0.5 * (config.learning_rate - config.min_learning_rate) * (
        1 + math.cos(math.pi * progress)
    )


def _epoch_generator(seed: int, epoch: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed * 1_000_003 + epoch)


def _global_batches(
    n_train: int, config: TrainConfig, epoch: int, latent_dim: int, dropout_width: int = 0
) -> Iterator[dict[str, torch.Tensor]]:
    """Every random draw of one epoch, for the global batches, identical on every rank.

    A decoder dropout mask ``(size, dropout_width)`` is drawn after the
    noise, and only when ``config.decoder_dropout`` > 0; the traversal
    penalty's dimensions and offsets last, and only when
    ``config.traversal_weight`` > 0: runs without them keep their stream
    (with ``traversal_directions = "any"`` a unit direction per sample is drawn
    after them and replaces the dimension); the factor supervision's pool rows,
    noise (and dropout mask) after them, and only when
    ``config.factor_weight`` > 0; the uniform noise of the latent's grid
    (``config.latent_grid``, latent units, for the real batch and then the
    factor batch) last, and only when ``config.latent_grid`` > 0.
    """
    generator = _epoch_generator(config.seed, epoch)
    order = torch.randperm(n_train, generator=generator)
    n_batches = max(1, n_train // config.batch_size)
    for b in range(n_batches):
        rows = order[b * config.batch_size : (b + 1) * config.batch_size]
        size = len(rows)
        permute = torch.rand(size, generator=generator) < config.permute_colours
        permutation = torch.randint(1, len(COLOUR_PERMUTATIONS), (size,), generator=generator) * permute
        mix = torch.rand(size, generator=generator) < config.mix_probability
        partner = torch.randint(0, n_train, (size,), generator=generator)
        weight = torch.where(mix, torch.rand(size, generator=generator), torch.ones(size))
        noise = torch.randn(size, latent_dim, generator=generator)
        draw = {"rows": rows, "permutation": permutation, "partner": partner, "weight": weight, "noise": noise}
        if config.decoder_dropout > 0:
            draw["keep"] = torch.rand(size, dropout_width, generator=generator) >= config.decoder_dropout
        if config.traversal_weight > 0:
            draw["traverse_dim"] = torch.randint(0, latent_dim, (size,), generator=generator)
            draw["traverse_offset"] = (2 * torch.rand(size, generator=generator) - 1) * config.traversal_range
            if config.traversal_directions == "any":
                direction = torch.randn(size, latent_dim, generator=generator)
                draw["traverse_dim"] = direction / direction.norm(dim=1, keepdim=True).clamp_min(1e-12)
        if config.factor_weight > 0:
            draw["factor_rows"] = torch.randint(0, config.factor_materials, (config.factor_batch,), generator=generator)
            draw["factor_noise"] = torch.randn(config.factor_batch, latent_dim, generator=generator)
            if config.decoder_dropout > 0:
                draw["factor_keep"] = (torch.rand(config.factor_batch, dropout_width, generator=generator)
                                       >= config.decoder_dropout)
        if config.latent_grid > 0:
            step = 2.0 ** -config.latent_grid
            draw["grid_noise"] = (torch.rand(size, latent_dim, generator=generator) - 0.5) * step
            if config.factor_weight > 0:
                draw["factor_grid_noise"] = (torch.rand(config.factor_batch, latent_dim, generator=generator)
                                             - 0.5) * step
        yield draw


def _trajectory(config: dict[str, Any]) -> dict[str, Any]:
    """The settings that shape the training trajectory (run control such as time limits excluded)."""
    return {k: v for k, v in config.items() if k not in _RUN_CONTROL}


def _log_up_to(path: Path, epochs: int) -> None:
    """Drop the log records of epochs after the checkpoint's (a run killed between checkpoints wrote them; the
    resumed run writes them again)."""
    if not path.exists():
        return
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    kept = [line for line in lines if line.strip() and json.loads(line).get("epoch", 0) <= epochs]
    if len(kept) != len(lines):
        with atomic_output(path, overwrite=True) as tmp:
            tmp.write_text("".join(kept), encoding="utf-8")


def _atomic_save(obj: Any, path: Path) -> None:
    tmp = path.with_name(path.name + ".part")
    torch.save(obj, tmp)
    os.replace(tmp, path)


@dataclass
class _TrainingData:
    """What training reads from the dataset: inputs and masks of the training split, references for RelAE."""

    inputs: torch.Tensor
    masks: torch.Tensor
    val_inputs: Any
    reference: MappedReference | None
    monitored_inputs: Any
    train_reference: MappedReference | None
    info: dict[str, Any]
    traversal_penalty: TraversalPenalty | None = None
    factor_pool: FactorPool | None = None
    #: With ``TrainConfig.edge_slots``: the training materials' edge-slot targets and weights (as ``inputs``).
    edge_targets: torch.Tensor | None = None
    edge_weights: torch.Tensor | None = None


def _resident(data: _TrainingData, device: torch.device) -> None:
    """Keep the training inputs and masks on the training device, so that each step's augmentation (reflectance
    blend, colour permutation) runs there instead of on the host and crossing to the device.

    On a GPU, augmenting on the host and copying each batch across takes most of a step's time (documentation:
    Results, model v2 trials); the inputs and masks of a hundred materials fit in a small share of a GPU's memory.
    """
    data.inputs = data.inputs.to(device)
    data.masks = data.masks.to(device)
    if data.edge_targets is not None and data.edge_weights is not None:
        data.edge_targets = data.edge_targets.to(device)
        data.edge_weights = data.edge_weights.to(device)
    if data.factor_pool is not None:
        data.factor_pool.to(device)


@dataclass
class _Progress:
    """Where a run stands: the next epoch, the best validation RelAE so far and its epoch, the optimiser step."""

    first_epoch: int = 0
    best: float = math.inf
    best_epoch: int = -1
    step: int = 0
    evals_without_gain: int = 0


def _run_info(dataset_path: str | os.PathLike[str], model_config: ModelConfig, train_config: TrainConfig,
              world: _World) -> dict[str, Any]:
    """The facts of a run written to ``run.json``."""
    return {
        "model_config": json.loads(model_config.to_json()),
        "train_config": train_config.to_dict(),
        "dataset": str(Path(dataset_path).resolve()),
        "world_size": world.size,
        "brdfcodec_version": __version__,
        "torch_version": torch.__version__,
    }


def _initial_model(folder: str | os.PathLike[str], model_config: ModelConfig, run_info: dict[str, Any]) -> BetaVAE:
    """The exported model a fine-tuning run starts from (checked against ``model_config``); records it in
    ``run_info["initial_model"]``."""
    encoder, decoder, manifest = load_model(folder)
    if manifest.config != model_config:
        raise ValueError(f"{folder}: the initial model's configuration differs from the run's: "
                         f"{manifest.config.to_json()} against {model_config.to_json()}")
    model = BetaVAE(model_config)
    model.encoder.load_state_dict(encoder.state_dict())
    model.decoder.load_state_dict(decoder.state_dict())
    run_info["initial_model"] = {"folder": str(Path(folder).resolve()), "name": manifest.name,
                                 "decoder_sha256": manifest.decoder_sha256}
    return model


def _check_run_folder(out: Path, run_info: dict[str, Any], resume: bool) -> None:
    """Refuse a non-empty folder for a new run, or a resume with another trajectory."""
    if resume:
        stored = json.loads((out / "run.json").read_text())
        # Fields added after a run was started take their defaults (which reproduce the old behaviour).
        stored["model_config"] = json.loads(ModelConfig.from_dict(stored["model_config"]).to_json())
        stored["train_config"] = TrainConfig.from_dict(stored["train_config"]).to_dict()
        for key in ("model_config", "train_config"):
            if _trajectory(stored[key]) != _trajectory(run_info[key]):
                raise ValueError(f"{out}: cannot resume with a different {key.replace('_', ' ')}")
    elif out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out}: run folder is not empty (use --resume to continue it)")


def _held_out(dataset: BrdfDataset, config: TrainConfig) -> list[bool]:
    """Which materials the run holds out: the stored split, a fold (``config.folds``) or none
    (``config.all_materials``), and every family outside ``config.train_families``."""
    if config.all_materials:
        held = [False] * len(dataset.names)
    elif config.folds:
        seed = int(dataset.attribute("split_seed"))
        held = [fold == config.fold for fold in fold_by_family(dataset.names, dataset.families, folds=config.folds,
                                                                  seed=seed)]
    else:
        held = [side == VALIDATION for side in dataset.split]
    families = {name.strip() for name in config.train_families.split(",") if name.strip()}
    if families:
        unknown = sorted(families - set(dataset.families))
        if unknown:
            raise ValueError(f"train_families names families the dataset does not hold: {unknown}")
        held = [h or family not in families for h, family in zip(held, dataset.families, strict=True)]
    return held


def _edge_slots(dataset: BrdfDataset, rows: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Edge-slot targets and weights of the materials ``rows`` (:func:`edge_slot_targets`), (N, 63, 90, 90) each."""
    if not dataset.has_tables:
        raise DatasetError(dataset.path, "--edge-slots needs full tables; rebuild the dataset without --no-tables")
    targets = np.zeros((len(rows), *NETWORK_INPUT_SHAPE), dtype=np.float32)
    weights = np.zeros_like(targets)
    for n, index in enumerate(rows):
        table = dataset.table(index)
        targets[n], weights[n] = edge_slot_targets(table.values, table.mask)
    return torch.from_numpy(targets), torch.from_numpy(weights)


def _with_edge_slots(data: _TrainingData, x: torch.Tensor, m: torch.Tensor, rows: torch.Tensor,
                     partner: torch.Tensor, blend: torch.Tensor, permutation: torch.Tensor,
                     recon: str) -> tuple[torch.Tensor, torch.Tensor]:
    """The reconstruction target and weights of a batch with its edge slots: the blended, permuted input ``x``
    and mask ``m``, and at the slots that are edge slots of both blended materials their targets, blended and
    permuted the same way, with the smaller of the two weights (its square root for the squared error, so that
    the slot's squared error weighs as its weight)."""
    assert data.edge_targets is not None and data.edge_weights is not None
    edge = permute_colours(mix_physical(data.edge_targets[rows], data.edge_targets[partner], blend), permutation)
    weight = permute_colours(torch.minimum(data.edge_weights[rows], data.edge_weights[partner]), permutation)
    weight = torch.where(m, torch.zeros_like(weight), weight)  # a valid entry keeps its own target and weight 1
    if recon == "l2":
        weight = weight.sqrt()
    return torch.where(weight > 0, edge, x), m.to(x.dtype) + weight


def _load_training_data(dataset_path: str | os.PathLike[str], world: _World,
                        config: TrainConfig) -> _TrainingData:
    """Inputs of the training materials, and (on rank 0) the mapped references that RelAE is measured against."""
    with BrdfDataset(dataset_path) as dataset:
        held = _held_out(dataset, config)
        train_rows = [i for i, h in enumerate(held) if not h]
        val_rows = [i for i, h in enumerate(held) if h]
        if not train_rows:
            raise ValueError(f"{dataset_path}: no training materials")
        inputs = torch.from_numpy(dataset.inputs(train_rows))
        edges = _edge_slots(dataset, train_rows) if config.edge_slots else (None, None)
        # Training RelAE is monitored on a fixed subset (every 4th material), without augmentation.
        monitored = train_rows[::4]
        return _TrainingData(
            edge_targets=edges[0], edge_weights=edges[1],
            inputs=inputs,
            masks=torch.from_numpy(dataset.input_masks(train_rows)),
            val_inputs=dataset.inputs(val_rows),
            reference=MappedReference(dataset, val_rows) if world.is_main and val_rows else None,
            monitored_inputs=inputs[::4].numpy(),  # the rows of `monitored`, already in memory
            train_reference=MappedReference(dataset, monitored) if world.is_main else None,
            info={"source_kind": dataset.source_kind, "description": dataset.description,
                  "train": [dataset.names[i] for i in train_rows],
                  "validation": [dataset.names[i] for i in val_rows]},
        )


def _build_model(model_config: ModelConfig, train_config: TrainConfig, data: _TrainingData, world: _World,
                 out: Path, resume: bool, initial: BetaVAE | None = None
                 ) -> tuple[BetaVAE, torch.optim.Optimizer, _Progress, AveragedModel | None]:
    """A fresh model (linear basis fitted), a copy of ``initial`` (fine-tuning), or the one of the checkpoint, with
    its optimiser, progress and weight average (None unless ``average_from_epoch`` is set)."""
    torch.manual_seed(train_config.seed)
    model = BetaVAE(model_config)
    if initial is not None and not resume:
        model.load_state_dict(initial.state_dict())
    elif model_config.linear_basis and not resume:
        initialise_linear_basis(model, data.inputs)
    if train_config.linear_path_rate > 0:
        linear_path_trainable(model.decoder)  # before loading a checkpoint, whose path is float32 then
    model = model.to(world.device)
    optimizer = _optimizer(model, train_config)
    average = AveragedModel(model, use_buffers=False) if train_config.average_from_epoch else None
    progress = _Progress()
    if resume:
        state = load_checkpoint(out / CHECKPOINT, map_location=world.device, required={
            "model": dict, "optimizer": dict, "epoch": int, "best": (int, float), "best_epoch": int, "step": int})
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        if average is not None:
            average.load_state_dict(state["average"])
        progress = _Progress(state["epoch"], state["best"], state["best_epoch"], state["step"])
    return model, optimizer, progress, average


def _evaluated_model(model: BetaVAE, average: AveragedModel | None) -> BetaVAE:
    """The weights that validation measures and ``best.pt`` keeps: the running average once it holds a step (with
    the live model's buffers), else the live model."""
    if average is None or int(average.n_averaged) == 0:
        return model
    averaged: BetaVAE = average.module
    with torch.no_grad():
        for kept, live in zip(averaged.buffers(), model.buffers(), strict=True):
            kept.copy_(live)
    return averaged


def _optimizer(model: BetaVAE, train_config: TrainConfig) -> torch.optim.Optimizer:
    """Adam, or AdamW decaying only the weight matrices and kernels when ``weight_decay`` > 0.

    A trainable linear path (``linear_path_rate`` > 0) gets its own group, never decayed, whose learning rate is
    the schedule's times ``lr_scale`` (:func:`_train_epoch` applies it).
    """
    linear = [getattr(model.decoder, name) for name in ("basis_mean", "basis_components")
              if isinstance(getattr(model.decoder, name, None), torch.nn.Parameter)]
    linear_ids = {id(p) for p in linear}
    parameters = [p for p in model.parameters() if p.requires_grad and id(p) not in linear_ids]
    path_group = ([{"params": linear, "weight_decay": 0.0, "lr_scale": train_config.linear_path_rate}]
                  if linear else [])
    if train_config.weight_decay == 0:
        return torch.optim.Adam([{"params": parameters}, *path_group], lr=train_config.learning_rate)
    groups = [
        {"params": [p for p in parameters if p.ndim >= 2], "weight_decay": train_config.weight_decay},
        {"params": [p for p in parameters if p.ndim < 2], "weight_decay": 0.0},
        *path_group,
    ]
    return torch.optim.AdamW(groups, lr=train_config.learning_rate)


def _train_epoch(model: BetaVAE, forward: torch.nn.Module, optimizer: torch.optim.Optimizer, data: _TrainingData,
                 model_config: ModelConfig, train_config: TrainConfig, epoch: int, world: _World,
                 progress: _Progress, average: AveragedModel | None = None) -> dict[str, Any]:
    """One epoch of optimisation; returns the epoch's log record (losses averaged over every rank).

    ``average``, when given, takes the weights after every step of this epoch.
    """
    epoch_start = time.perf_counter()
    model.train()
    n_train = len(data.inputs)
    local = train_config.batch_size // world.size
    steps_per_epoch = max(1, n_train // train_config.batch_size)
    # loss, recon, kl, traversal penalty, factor supervision, latent rate (sums over samples), the KL of each dimension
    sums = torch.zeros(6, dtype=torch.float64, device=world.device)
    kl_dims = torch.zeros(model_config.latent_dim, dtype=torch.float64, device=world.device)
    count = 0
    dropout = (DecoderHiddenDropout(model.decoder, train_config.decoder_dropout)
               if train_config.decoder_dropout > 0 else None)
    width = dropout.width if dropout is not None else 0
    penalty = data.traversal_penalty  # built only when traversal_weight > 0
    pool = data.factor_pool  # built only when factor_weight > 0
    factor_local = train_config.factor_batch // world.size
    for draw in _global_batches(n_train, train_config, epoch, model_config.latent_dim, width):
        part = slice(world.rank * local, (world.rank + 1) * local)
        if dropout is not None:
            dropout.set_keep(draw["keep"][part])
        # The draws are made on the CPU (the same stream on every device); the augmentation runs on the training
        # device, where the training set lives (`_resident`).
        rows, partner = draw["rows"][part].to(world.device), draw["partner"][part].to(world.device)
        permutation = draw["permutation"][part].to(world.device)
        x = mix_physical(data.inputs[rows], data.inputs[partner], draw["weight"][part].to(world.device))
        x = permute_colours(x, permutation)
        m = permute_colours(data.masks[rows] & data.masks[partner], permutation)
        rate = _learning_rate(progress.step, steps_per_epoch, train_config)
        for group in optimizer.param_groups:
            group["lr"] = rate * group.get("lr_scale", 1.0)
        noise = draw["noise"][part].to(world.device)
        grid_noise = draw["grid_noise"][part].to(world.device) if "grid_noise" in draw else None
        factor = x.new_zeros(())
        if pool is None:
            recon, mu, logvar = forward(x, noise, grid_noise)
        else:
            # The analytic materials go through the same forward pass (one call: DistributedDataParallel allows
            # one forward per backward); GroupNorm is per sample, so they do not change the others' outputs.
            fpart = slice(world.rank * factor_local, (world.rank + 1) * factor_local)
            frows = draw["factor_rows"][fpart].to(world.device)
            if dropout is not None:
                dropout.set_keep(torch.cat([draw["keep"][part], draw["factor_keep"][fpart]]))
            all_grid_noise = (None if grid_noise is None else
                              torch.cat([grid_noise, draw["factor_grid_noise"][fpart].to(world.device)]))
            recon_all, mu_all, logvar_all = forward(torch.cat([x, pool.inputs[frows]]),
                                                    torch.cat([noise, draw["factor_noise"][fpart].to(world.device)]),
                                                    all_grid_noise)
            if dropout is not None:
                dropout.set_keep(draw["keep"][part])  # the traversal's decode below has the real batch only
            n_real = len(x)
            recon, mu, logvar = recon_all[:n_real], mu_all[:n_real], logvar_all[:n_real]
            analytic = beta_vae_loss(recon_all[n_real:], pool.inputs[frows], pool.masks[frows], mu_all[n_real:],
                                     logvar_all[n_real:], beta=train_config.beta, recon=train_config.recon)
            factor = factor_supervision_loss(mu_all[n_real:], pool.targets[frows], pool.weights[frows])
        target, weights = x, m
        if data.edge_targets is not None and data.edge_weights is not None:
            target, weights = _with_edge_slots(data, x, m, rows, partner, draw["weight"][part].to(world.device),
                                               permutation, train_config.recon)
        terms = beta_vae_loss(recon, target, weights, mu, logvar, beta=train_config.beta, recon=train_config.recon)
        loss, traversal, rate = terms.loss, terms.loss.new_zeros(()), terms.loss.new_zeros(())
        if grid_noise is not None:
            # The codec's R (nats per material) of the real batch's μ on the grid, rounding as uniform noise.
            rate = latent_rate(mu + grid_noise, 2.0 ** -train_config.latent_grid).sum(dim=1).mean()
            if train_config.rate_weight > 0:
                loss = loss + train_config.rate_weight * rate
        if pool is not None:
            loss = loss + analytic.loss + train_config.factor_weight * factor
        if train_config.mean_recon_weight > 0:
            # The decode of μ itself, through the module (as the traversal's below), for the real batch and the
            # analytic one, each term a batch mean of per-material sums, as the β-VAE's reconstruction.
            mus, targets, valid = (mu, target, weights) if pool is None else (
                mu_all, torch.cat([target, pool.inputs[frows]]),
                torch.cat([weights, pool.masks[frows].to(weights.dtype)]))
            at_mean = masked_recon_per_sample(model.decoder.unbounded(mus), targets, valid, train_config.recon)
            mean_recon = at_mean[: len(x)].mean() + (at_mean[len(x):].mean() if pool is not None else 0.0)
            loss = loss + train_config.mean_recon_weight * mean_recon
        if penalty is not None:
            # Through the module, not the DDP wrapper: autograd adds this use of a weight to the wrapper's before
            # DDP reduces the gradient (reasoned, not yet tested under torchrun with the penalty).
            edited = model.decoder.unbounded(
                traversed_codes(mu, draw["traverse_dim"][part], draw["traverse_offset"][part]))
            traversal = penalty(edited, x).total().mean()
            loss = loss + train_config.traversal_weight * traversal
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if average is not None:
            average.update_parameters(model)
        progress.step += 1
        n = len(rows)
        # Summed on the training device: no synchronisation per step.
        sums += torch.stack([loss, terms.recon, terms.kl, traversal, factor, rate]).detach().double() * n
        kl_dims += kl_per_dimension(mu.detach(), logvar.detach()).sum(0).double()
        count += n
    if dropout is not None:
        dropout.remove()
    totals = torch.cat([sums, kl_dims, torch.tensor([count], dtype=torch.float64, device=world.device)])
    if world.size > 1:
        dist.all_reduce(totals)
    count_all = totals[-1].item()
    return {
        "epoch": epoch + 1,
        "lr": optimizer.param_groups[0]["lr"],
        "loss": totals[0].item() / count_all,
        "recon": totals[1].item() / count_all,
        "kl": totals[2].item() / count_all,
        "traversal": totals[3].item() / count_all,
        "factor": totals[4].item() / count_all,
        "rate_bits": totals[5].item() / count_all / math.log(2),
        "kl_per_dim": [v / count_all for v in totals[6:-1].tolist()],
        "seconds": time.perf_counter() - epoch_start,
    }


def _evaluate(model: BetaVAE, data: _TrainingData, world: _World) -> dict[str, float]:
    """Validation (and monitored training) mapped RelAE of ``decoder(μ(x))``."""
    if data.reference is None:
        return {}
    errors = data.reference.relae(reconstruct_mapped(model, data.val_inputs, device=world.device))
    record = {"val_relae_mapped": float(errors.mean()), "val_relae_mapped_max": float(errors.max())}
    if data.train_reference is not None:
        train_errors = data.train_reference.relae(reconstruct_mapped(model, data.monitored_inputs, device=world.device))
        record["train_relae_mapped"] = float(train_errors.mean())
    return record


def _keep_if_best(model: BetaVAE, model_config: ModelConfig, record: dict[str, Any], progress: _Progress,
                  out: Path, keep: str = "best") -> None:
    """Save ``best.pt`` when the validation RelAE improved (every time with ``keep="last"``); count evaluations
    without gain otherwise."""
    if record["val_relae_mapped"] < progress.best or keep == "last":
        progress.best, progress.best_epoch = record["val_relae_mapped"], record["epoch"]
        _atomic_save({"model": model.state_dict(), "epoch": record["epoch"], "model_config": model_config.to_json()},
                     out / BEST)
        progress.evals_without_gain = 0
    else:
        progress.evals_without_gain += 1


def _stop_reason(train_config: TrainConfig, progress: _Progress, done: int, elapsed: float) -> str | None:
    """Why to stop after epoch ``done`` (early stopping, time limit), or None to go on."""
    stop = None
    if train_config.patience and progress.evals_without_gain >= train_config.patience:
        stop = "early stopping"
    out_of_time = train_config.time_limit_s is not None and elapsed >= train_config.time_limit_s
    if out_of_time and done < train_config.epochs:
        stop = "time limit"
    return stop


def train(
    dataset_path: str | os.PathLike[str],
    run_dir: str | os.PathLike[str],
    *,
    model_config: ModelConfig,
    train_config: TrainConfig,
    resume: bool = False,
    progress: bool = True,
    initial_model: str | os.PathLike[str] | None = None,
) -> TrainResult:
    """Train a β-VAE on the training split of a dataset.

    Parameters
    ----------
    dataset_path : str or os.PathLike
        Dataset file of ``bvae dataset build`` (with full tables, for RelAE).
    run_dir : str or os.PathLike
        Output folder; must be empty or absent unless ``resume``.
    model_config, train_config : ModelConfig, TrainConfig
        Architecture and schedule. On resume they must equal the stored ones.
    resume : bool, default False
        Continue from ``run_dir/checkpoint.pt``.
    progress : bool, default True
        Progress bar on stderr (rank 0).
    initial_model : str or os.PathLike, optional
        An exported model folder to start from instead of fresh weights (fine-tuning; for example a model whose
        latent was turned by ``bvae model export --align-factors``, so that an axis penalty acts on its
        aligned axes). Its configuration must equal ``model_config``; ``run.json`` records its name and
        decoder hash.

    Returns
    -------
    TrainResult
    """
    world = _setup_world()
    start_time = time.perf_counter()
    out = Path(run_dir)
    if train_config.batch_size % world.size:
        raise ValueError(f"batch_size {train_config.batch_size} is not divisible by {world.size} processes")
    if train_config.factor_weight > 0 and train_config.factor_batch % world.size:
        raise ValueError(f"factor_batch {train_config.factor_batch} is not divisible by {world.size} processes")
    if train_config.linear_path_rate > 0 and not model_config.linear_basis:
        raise ValueError("linear_path_rate > 0 needs a model with a linear path (ModelConfig.linear_basis)")
    run_info = _run_info(dataset_path, model_config, train_config, world)
    initial = _initial_model(initial_model, model_config, run_info) if initial_model is not None else None
    _check_run_folder(out, run_info, resume)
    data = _load_training_data(dataset_path, world, train_config)
    if train_config.traversal_weight > 0:
        data.traversal_penalty = TraversalPenalty(
            data.inputs, hole_margin=train_config.traversal_hole_margin,
            pit_weight=train_config.traversal_pit_weight).to(world.device)
    if train_config.factor_weight > 0:
        data.factor_pool = build_factor_pool(train_config.factor_materials, train_config.factor_seed,
                                             model_config.latent_dim, saturation=train_config.factor_saturation,
                                             alpha_min=train_config.factor_alpha_min)
    run_info["data"] = data.info
    model, optimizer, state, average = _build_model(model_config, train_config, data, world, out, resume, initial)
    _resident(data, world.device)
    if world.is_main and not resume:
        out.mkdir(parents=True, exist_ok=True)
        (out / "run.json").write_text(json.dumps(run_info, indent=2))
    if world.is_main and resume:
        _log_up_to(out / LOG, state.first_epoch)
    ddp = DistributedDataParallel(model) if world.size > 1 else None
    forward = ddp if ddp is not None else model

    first_epoch = state.first_epoch
    stop_reason = "completed"
    bar = tqdm(range(first_epoch, train_config.epochs), initial=first_epoch, total=train_config.epochs,
               desc="epochs", unit="ep", disable=not (progress and world.is_main))
    epoch = first_epoch
    for epoch in bar:
        averaging = average if average is not None and epoch + 1 >= train_config.average_from_epoch else None
        record = _train_epoch(model, forward, optimizer, data, model_config, train_config, epoch, world, state,
                              averaging)
        done = epoch + 1
        if averaging is not None:
            record["averaged_steps"] = int(averaging.n_averaged)
        evaluation_due = done % train_config.eval_every == 0 or done == train_config.epochs
        if data.reference is not None and evaluation_due:
            evaluated = _evaluated_model(model, average)
            record.update(_evaluate(evaluated, data, world))
            _keep_if_best(evaluated, model_config, record, state, out, train_config.keep)
        elif evaluation_due and world.is_main and not data.info["validation"]:
            # Nothing held out (a release trained on every material): best.pt holds the last weights.
            state.best_epoch = done
            _atomic_save({"model": _evaluated_model(model, average).state_dict(), "epoch": done,
                          "model_config": model_config.to_json()}, out / BEST)
        stop = _stop_reason(train_config, state, done, time.perf_counter() - start_time)
        stop_flag = torch.tensor([1.0 if stop else 0.0], device=world.device)  # NCCL reduces device tensors only
        if world.size > 1:
            dist.broadcast(stop_flag, 0)
        if world.is_main:
            with open(out / LOG, "a", encoding="utf-8") as log:
                log.write(json.dumps(record) + "\n")
            bar.set_postfix(loss=f"{record['loss']:.4g}", val=f"{state.best:.4f}", refresh=False)
            if done % train_config.checkpoint_every == 0 or stop_flag.item() or done == train_config.epochs:
                checkpoint = {"model": model.state_dict(), "optimizer": optimizer.state_dict(), "epoch": done,
                              "best": state.best, "best_epoch": state.best_epoch, "step": state.step}
                if average is not None:
                    checkpoint["average"] = average.state_dict()
                _atomic_save(checkpoint, out / CHECKPOINT)
        if stop_flag.item():
            stop_reason = stop or "stopped by rank 0"
            break
    bar.close()
    seconds = time.perf_counter() - start_time
    result = TrainResult(out, epoch + 1 if train_config.epochs > first_epoch else first_epoch, state.best_epoch,
                         state.best, stop_reason, seconds)
    if world.is_main:
        summary = {"epochs_done": result.epochs_done, "best_epoch": state.best_epoch,
                   "best_validation_relae_mapped": state.best, "stop_reason": stop_reason,
                   "seconds_this_session": seconds}
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if world.size > 1:
        with contextlib.suppress(Exception):
            dist.barrier()
    return result
