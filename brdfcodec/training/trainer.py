"""The training loop: one process on CPU or GPU, or many under ``torchrun``.

A run directory holds ``run.json`` (configs, dataset, world size),
``log.jsonl`` (one JSON object per epoch), ``checkpoint.pt`` (everything
needed to resume), ``best.pt`` (weights with the best validation RelAE) and
``summary.json`` at the end.

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

import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel
from tqdm.auto import tqdm

from brdfcodec.dataset import BrdfDataset
from brdfcodec.models.config import ModelConfig
from brdfcodec.models.loss import beta_vae_loss, kl_per_dimension
from brdfcodec.models.network import BetaVAE, initialise_linear_basis
from brdfcodec.training.augment import COLOUR_PERMUTATIONS, mix_physical, permute_colours
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.evaluation import MappedReference, reconstruct_mapped
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
    n_train: int, config: TrainConfig, epoch: int, latent_dim: int
) -> Iterator[dict[str, torch.Tensor]]:
    """Every random draw of one epoch, for the global batches, identical on every rank."""
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
        yield {"rows": rows, "permutation": permutation, "partner": partner, "weight": weight, "noise": noise}


def _trajectory(config: dict[str, Any]) -> dict[str, Any]:
    """The settings that shape the training trajectory (run control such as time limits excluded)."""
    return {k: v for k, v in config.items() if k not in _RUN_CONTROL}


def _atomic_save(obj: Any, path: Path) -> None:
    tmp = path.with_name(path.name + ".part")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def train(
    dataset_path: str | os.PathLike[str],
    run_dir: str | os.PathLike[str],
    *,
    model_config: ModelConfig,
    train_config: TrainConfig,
    resume: bool = False,
    progress: bool = True,
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

    Returns
    -------
    TrainResult
    """
    world = _setup_world()
    start_time = time.perf_counter()
    out = Path(run_dir)
    if train_config.batch_size % world.size:
        raise ValueError(f"batch_size {train_config.batch_size} is not divisible by {world.size} processes")
    run_info = {
        "model_config": json.loads(model_config.to_json()),
        "train_config": train_config.to_dict(),
        "dataset": str(Path(dataset_path).resolve()),
        "world_size": world.size,
        "brdfcodec_version": __version__,
        "torch_version": torch.__version__,
    }
    if resume:
        stored = json.loads((out / "run.json").read_text())
        for key in ("model_config", "train_config"):
            if _trajectory(stored[key]) != _trajectory(run_info[key]):
                raise ValueError(f"{out}: cannot resume with a different {key.replace('_', ' ')}")
    elif out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out}: run folder is not empty (use --resume to continue it)")

    with BrdfDataset(dataset_path) as dataset:
        train_rows = dataset.indices("train")
        val_rows = dataset.indices("validation")
        if not train_rows:
            raise ValueError(f"{dataset_path}: no training materials")
        inputs = torch.from_numpy(dataset.inputs(train_rows))
        masks = torch.from_numpy(dataset.input_masks(train_rows))
        val_inputs = dataset.inputs(val_rows)
        reference = MappedReference(dataset, val_rows) if world.is_main and val_rows else None
        # Training RelAE is monitored on a fixed subset (every 4th material), without augmentation.
        monitored = train_rows[::4]
        train_reference = MappedReference(dataset, monitored) if world.is_main else None
        monitored_inputs = inputs[::4].numpy()  # the rows of `monitored`, already in memory
        data_info = {"source_kind": dataset.source_kind, "description": dataset.description,
                     "train": [dataset.names[i] for i in train_rows],
                     "validation": [dataset.names[i] for i in val_rows]}
    run_info["data"] = data_info

    torch.manual_seed(train_config.seed)
    model = BetaVAE(model_config)
    if model_config.linear_basis and not resume:
        initialise_linear_basis(model, inputs)
    model = model.to(world.device)
    optimizer = torch.optim.Adam(model.parameters(), lr=train_config.learning_rate)
    first_epoch, best, best_epoch, step = 0, math.inf, -1, 0
    if resume:
        state = torch.load(out / CHECKPOINT, map_location=world.device, weights_only=False)
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        first_epoch, best, best_epoch, step = state["epoch"], state["best"], state["best_epoch"], state["step"]
    elif world.is_main:
        out.mkdir(parents=True, exist_ok=True)
        (out / "run.json").write_text(json.dumps(run_info, indent=2))
    ddp = DistributedDataParallel(model) if world.size > 1 else None
    forward = ddp if ddp is not None else model

    local = train_config.batch_size // world.size
    steps_per_epoch = max(1, len(train_rows) // train_config.batch_size)
    stop_reason = "completed"
    evals_without_gain = 0
    bar = tqdm(range(first_epoch, train_config.epochs), initial=first_epoch, total=train_config.epochs,
               desc="epochs", unit="ep", disable=not (progress and world.is_main))
    epoch = first_epoch
    for epoch in bar:
        epoch_start = time.perf_counter()
        model.train()
        sums = torch.zeros(3, dtype=torch.float64)  # loss, recon, kl (sums over samples)
        kl_dims = torch.zeros(model_config.latent_dim, dtype=torch.float64)
        count = 0
        for draw in _global_batches(len(train_rows), train_config, epoch, model_config.latent_dim):
            part = slice(world.rank * local, (world.rank + 1) * local)
            rows, partner = draw["rows"][part], draw["partner"][part]
            x = mix_physical(inputs[rows], inputs[partner], draw["weight"][part])
            m = masks[rows] & masks[partner]
            x = permute_colours(x, draw["permutation"][part]).to(world.device)
            m = permute_colours(m, draw["permutation"][part]).to(world.device)
            for group in optimizer.param_groups:
                group["lr"] = _learning_rate(step, steps_per_epoch, train_config)
            recon, mu, logvar = forward(x, draw["noise"][part].to(world.device))
            terms = beta_vae_loss(recon, x, m, mu, logvar, beta=train_config.beta, recon=train_config.recon)
            optimizer.zero_grad(set_to_none=True)
            terms.loss.backward()
            optimizer.step()
            step += 1
            n = len(rows)
            sums += torch.tensor([terms.loss.item(), terms.recon.item(), terms.kl.item()], dtype=torch.float64) * n
            kl_dims += kl_per_dimension(mu.detach(), logvar.detach()).sum(0).double().cpu()
            count += n
        totals = torch.cat([sums, kl_dims, torch.tensor([count], dtype=torch.float64)])
        if world.size > 1:
            dist.all_reduce(totals)
        count_all = totals[-1].item()
        record: dict[str, Any] = {
            "epoch": epoch + 1,
            "lr": optimizer.param_groups[0]["lr"],
            "loss": totals[0].item() / count_all,
            "recon": totals[1].item() / count_all,
            "kl": totals[2].item() / count_all,
            "kl_per_dim": [v / count_all for v in totals[3:-1].tolist()],
            "seconds": time.perf_counter() - epoch_start,
        }
        done = epoch + 1
        evaluate = reference is not None and (done % train_config.eval_every == 0 or done == train_config.epochs)
        if evaluate and reference is not None:
            errors = reference.relae(reconstruct_mapped(model, val_inputs, device=world.device))
            record["val_relae_mapped"] = float(errors.mean())
            record["val_relae_mapped_max"] = float(errors.max())
            if train_reference is not None:
                train_errors = train_reference.relae(reconstruct_mapped(model, monitored_inputs, device=world.device))
                record["train_relae_mapped"] = float(train_errors.mean())
            if record["val_relae_mapped"] < best:
                best, best_epoch = record["val_relae_mapped"], done
                _atomic_save({"model": model.state_dict(), "epoch": done, "model_config": model_config.to_json()},
                             out / BEST)
                evals_without_gain = 0
            else:
                evals_without_gain += 1
        elapsed = time.perf_counter() - start_time
        stop = None
        if train_config.patience and evals_without_gain >= train_config.patience:
            stop = "early stopping"
        out_of_time = train_config.time_limit_s is not None and elapsed >= train_config.time_limit_s
        if out_of_time and done < train_config.epochs:
            stop = "time limit"
        stop_flag = torch.tensor([1.0 if stop else 0.0])
        if world.size > 1:
            dist.broadcast(stop_flag, 0)
        if world.is_main:
            with open(out / LOG, "a", encoding="utf-8") as log:
                log.write(json.dumps(record) + "\n")
            bar.set_postfix(loss=f"{record['loss']:.4g}", val=f"{best:.4f}", refresh=False)
            if done % train_config.checkpoint_every == 0 or stop_flag.item() or done == train_config.epochs:
                _atomic_save({"model": model.state_dict(), "optimizer": optimizer.state_dict(), "epoch": done,
                              "best": best, "best_epoch": best_epoch, "step": step}, out / CHECKPOINT)
        if stop_flag.item():
            stop_reason = stop or "stopped by rank 0"
            break
    bar.close()
    seconds = time.perf_counter() - start_time
    result = TrainResult(out, epoch + 1 if train_config.epochs > first_epoch else first_epoch, best_epoch,
                         best, stop_reason, seconds)
    if world.is_main:
        summary = {"epochs_done": result.epochs_done, "best_epoch": best_epoch, "best_validation_relae_mapped": best,
                   "stop_reason": stop_reason, "seconds_this_session": seconds}
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if world.size > 1:
        with contextlib.suppress(Exception):
            dist.barrier()
    return result
