"""Measurements of a trained model for its card: per-material errors, PCA baseline, KL, traversals."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch

from brdfcodec.baselines.pca import fit_pca
from brdfcodec.dataset import BrdfDataset
from brdfcodec.metrics import relae_linear, relae_mapped
from brdfcodec.models.loss import kl_per_dimension
from brdfcodec.models.network import Decoder, Encoder
from brdfcodec.transforms import table_from_network_output

__all__ = [
    "MaterialError",
    "encode_dataset",
    "kl_per_dim",
    "material_errors",
    "pca_errors",
    "summarise",
    "traversal_changes",
]


@dataclass(frozen=True)
class MaterialError:
    """RelAE of one material's reconstruction (``spec/conventions.md`` §8)."""

    name: str
    split: str
    relae_mapped: float
    relae_linear: float

    def as_dict(self) -> dict[str, object]:
        """JSON-ready dictionary."""
        return asdict(self)


@torch.no_grad()
def encode_dataset(encoder: Encoder, inputs: np.ndarray, batch_size: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Posterior ``(μ, log σ²)`` of each input, each ``(n, latent_dim)``."""
    mus, logvars = [], []
    for start in range(0, len(inputs), batch_size):
        mu, logvar = encoder(torch.from_numpy(np.ascontiguousarray(inputs[start : start + batch_size])))
        mus.append(mu.numpy())
        logvars.append(logvar.numpy())
    return np.concatenate(mus), np.concatenate(logvars)


@torch.no_grad()
def _decode(decoder: Decoder, latents: np.ndarray) -> np.ndarray:
    return decoder(torch.from_numpy(latents.astype(np.float32))).numpy()


def _errors_of(dataset: BrdfDataset, indices: Sequence[int], mapped_outputs: np.ndarray) -> list[MaterialError]:
    rows = []
    for k, index in enumerate(indices):
        reference = dataset.table(index)
        estimate = table_from_network_output(mapped_outputs[k]).astype(np.float64)
        rows.append(MaterialError(
            dataset.names[index], dataset.split[index],
            relae_mapped(reference.values, estimate, reference.mask).overall,
            relae_linear(reference.values, estimate, reference.mask).overall,
        ))
    return rows


def material_errors(encoder: Encoder, decoder: Decoder, dataset: BrdfDataset) -> list[MaterialError]:
    """Errors of ``decoder(μ(x))`` for every material of the dataset, on the full table."""
    rows: list[MaterialError] = []
    for index in range(len(dataset)):
        inputs = dataset.inputs([index])
        mu, _ = encode_dataset(encoder, inputs)
        rows += _errors_of(dataset, [index], _decode(decoder, mu))
    return rows


def pca_errors(dataset: BrdfDataset, n_components: int) -> list[MaterialError]:
    """Errors of a PCA basis of the mapped inputs fitted on the training split."""
    basis = fit_pca(dataset.inputs(dataset.indices("train")), n_components)
    rows: list[MaterialError] = []
    for index in range(len(dataset)):
        inputs = dataset.inputs([index])
        rows += _errors_of(dataset, [index], basis.decode(basis.encode(inputs)))
    return rows


def summarise(rows: Sequence[MaterialError]) -> dict[str, dict[str, float]]:
    """Mean and worst RelAE (mapped and linear) per split."""
    out: dict[str, dict[str, float]] = {}
    for split in ("train", "validation"):
        chosen = [r for r in rows if r.split == split]
        if not chosen:
            continue
        mapped = np.array([r.relae_mapped for r in chosen])
        linear = np.array([r.relae_linear for r in chosen])
        out[split] = {
            "count": len(chosen),
            "mapped_mean": float(mapped.mean()), "mapped_max": float(mapped.max()),
            "mapped_worst": chosen[int(mapped.argmax())].name,
            "linear_mean": float(linear.mean()), "linear_max": float(linear.max()),
        }
    return out


def kl_per_dim(encoder: Encoder, inputs: np.ndarray) -> list[float]:
    """Mean KL (nats) of each latent dimension over the given inputs."""
    mu, logvar = encode_dataset(encoder, inputs)
    return kl_per_dimension(torch.from_numpy(mu), torch.from_numpy(logvar)).mean(0).tolist()


@torch.no_grad()
def traversal_changes(decoder: Decoder, centre: np.ndarray, spread: np.ndarray) -> list[dict[str, float]]:
    """How much each latent dimension changes the decoded material.

    For dimension j, decode ``centre`` with ``z_j = centre_j ± 3·spread_j``
    and measure the mean absolute difference of the mapped slices between
    −3 and +3 (and relative to the mean mapped value at the centre).

    Parameters
    ----------
    centre : ndarray, shape (M,)
        Latent around which to traverse (e.g. the mean of the training μ).
    spread : ndarray, shape (M,)
        Unit of the traversal per dimension (e.g. the std of the training μ).
    """
    base = _decode(decoder, centre[None])[0]
    scale = float(np.abs(base).mean())
    rows = []
    for j in range(len(centre)):
        low, high = centre.copy(), centre.copy()
        low[j] -= 3 * spread[j]
        high[j] += 3 * spread[j]
        a, b = _decode(decoder, np.stack([low, high]))
        change = float(np.abs(b - a).mean())
        colour = b.reshape(3, -1).mean(1) - a.reshape(3, -1).mean(1)
        rows.append({"dimension": j + 1, "mean_abs_change_mapped": change, "relative_change": change / scale,
                     "mean_change_rgb": [float(c) for c in colour]})
    return rows
