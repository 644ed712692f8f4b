"""Measurements of a trained model for its card: per-material errors, PCA baseline, KL, traversals.

(The size / error / time report of ``bvae bench report`` is :mod:`brdfcodec.report`; this module measures
one model for its model card.) The networks run through :class:`~brdfcodec.codec.BrdfEncoder` and
:class:`~brdfcodec.codec.BrdfDecoder`, as a shipped model runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch

from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.models.loss import kl_per_dimension
from brdfcodec.models.network import Decoder, Encoder
from brdfcodec.models.pca import fit_pca
from brdfcodec.representation import table_from_mapped, table_from_network_output
from brdfcodec.representation.metrics import relae_linear, relae_mapped

__all__ = [
    "MaterialErrors",
    "ModelMeasurements",
    "encode_dataset",
    "kl_per_dim",
    "measure_model",
    "summarise",
    "traversal_changes",
]


@dataclass(frozen=True)
class MaterialErrors:
    """RelAE of one material's reconstruction (``spec/conventions.md`` §8)."""

    name: str
    split: str
    relae_mapped: float
    relae_linear: float

    def as_dict(self) -> dict[str, object]:
        """JSON-ready dictionary."""
        return asdict(self)


@dataclass(frozen=True)
class ModelMeasurements:
    """Everything :func:`measure_model` measures, each material's table read and decoded once.

    Attributes
    ----------
    errors, pca_errors : list of MaterialErrors
        The model's ``decoder(μ(x))`` and the PCA baseline, per material in dataset order.
    mu, logvar : ndarray, shape (n_materials, latent_dim)
        Posterior of every material.
    """

    errors: list[MaterialErrors]
    pca_errors: list[MaterialErrors]
    mu: np.ndarray
    logvar: np.ndarray


def encode_dataset(encoder: Encoder, inputs: np.ndarray, batch_size: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Posterior ``(μ, log σ²)`` of each input, each ``(n, latent_dim)``."""
    return BrdfEncoder.from_network(encoder).posterior_from_inputs(inputs, batch_size=batch_size, log_variance=True)


def _errors(name: str, split: str, reference: MerlBRDF, estimate: np.ndarray) -> MaterialErrors:
    values = estimate.astype(np.float64)
    return MaterialErrors(name, split, relae_mapped(reference.values, values, reference.mask).overall,
                          relae_linear(reference.values, values, reference.mask).overall)


def measure_model(encoder: Encoder, decoder: Decoder, dataset: BrdfDataset, pca_components: int,
                  train_rows: Sequence[int] | None = None) -> ModelMeasurements:
    """Errors of the model and of a PCA basis (fitted on the training materials) on every material's full table.

    ``train_rows`` are the materials the model trained on (by default the dataset's training split); every
    other material is reported as ``"validation"``. Each material's reference table is read once and its input
    encoded once.
    """
    trained = set(dataset.indices("train") if train_rows is None else train_rows)
    basis = fit_pca(dataset.inputs(sorted(trained)), pca_components)
    mu, logvar = encode_dataset(encoder, dataset.inputs(list(range(len(dataset)))))
    runner = BrdfDecoder.from_network(decoder)
    errors, baseline = [], []
    for index in range(len(dataset)):
        name, split = dataset.names[index], "train" if index in trained else "validation"
        reference = dataset.table(index)
        errors.append(_errors(name, split, reference, table_from_mapped(runner.decode_mapped(mu[index]))))
        pca_output = basis.decode(basis.encode(dataset.inputs([index])))[0]
        baseline.append(_errors(name, split, reference, table_from_network_output(pca_output)))
    return ModelMeasurements(errors, baseline, mu, logvar)


def summarise(rows: Sequence[MaterialErrors]) -> dict[str, dict[str, float]]:
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


def kl_per_dim(mu: np.ndarray, logvar: np.ndarray) -> list[float]:
    """Mean KL (nats) of each latent dimension over the given posteriors."""
    return kl_per_dimension(torch.from_numpy(mu), torch.from_numpy(logvar)).mean(0).tolist()


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
    runner = BrdfDecoder.from_network(decoder)
    base = runner.decode_mapped(centre)
    scale = float(np.abs(base).mean())
    rows = []
    for j in range(len(centre)):
        low, high = centre.copy(), centre.copy()
        low[j] -= 3 * spread[j]
        high[j] += 3 * spread[j]
        a, b = runner.decode_mapped(np.stack([low, high]))
        change = float(np.abs(b - a).mean())
        colour = b.reshape(3, -1).mean(1) - a.reshape(3, -1).mean(1)
        rows.append({"dimension": j + 1, "mean_abs_change_mapped": change, "relative_change": change / scale,
                     "mean_change_rgb": [float(c) for c in colour]})
    return rows
