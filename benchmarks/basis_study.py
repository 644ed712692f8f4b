"""Which shared basis for the basis layer, and what the joint fit adds (issue 14; ``brdfcodec/layers/basis.py``).

Usage::

    python benchmarks/basis_study.py DATASET.h5 [-o reports/rd-study/basis.json]

On the dataset's held-out (validation) materials, kept-slice mapped RelAE
(valid entries, the base clamped as the decoder clamps it) of:

- ``pca``: PCA-k of the training split (mean + least-squares coefficients);
- ``base+data``: the shipped model's refined base (effort 3) plus k
  least-squares coefficients on the training *data*'s principal components;
- ``base+residual``: the same on the principal components of the training
  materials' *residuals* (what the decoder leaves on the materials it was
  trained on);
- ``base+data joint``: μ and the k coefficients fitted together on the
  mapped L1 error (:func:`brdfcodec.codec.refine.fit_basis_coefficients`
  at effort 3), as the encoder does, before quantisation.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from brdfcodec.codec import BrdfEncoder
from brdfcodec.conventions import MAPPED_MAX
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.codec.refine import fit_basis_coefficients, refine_latent

COUNTS = (4, 8, 16, 30, 48, 64)


def study_arguments(
    doc: str, default_output: str, extra: Callable[[argparse.ArgumentParser], None] | None = None
) -> argparse.Namespace:
    """The command line every study script shares: a dataset file and ``-o OUTPUT.json`` (and what ``extra``
    adds); torch on one thread."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("-o", "--output", type=Path, default=Path(default_output))
    if extra is not None:
        extra(parser)
    args = parser.parse_args()
    torch.set_num_threads(1)
    return args


@contextmanager
def replaced(module: Any, name: str, value: Any, active: bool = True) -> Iterator[None]:
    """``module.name`` replaced by ``value`` inside the block (when ``active``), to compare an encoder rule with
    another one in the same run."""
    original = getattr(module, name)
    if active:
        setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, original)


@dataclass(frozen=True)
class HeldOut:
    """A dataset's held-out (validation) materials, as the study scripts use them."""

    inputs: np.ndarray  # (N, 63, 90, 90) mapped kept slices
    masks: np.ndarray  # (N, 63, 90, 90) validity
    tables: list[Any]  # full source tables (MerlBRDF)
    names: list[str]
    description: str


def held_out_materials(path: Path) -> HeldOut:
    """The held-out materials of the dataset at ``path``, with their full tables."""
    with BrdfDataset(path) as dataset:
        held = dataset.indices("validation")
        return HeldOut(dataset.inputs(held), dataset.input_masks(held), [dataset.table(i) for i in held],
                       [dataset.names[i] for i in held], dataset.description)


def kept_slice_relae(estimate: np.ndarray, inputs: np.ndarray, masks: np.ndarray) -> float:
    error = (np.abs(np.clip(estimate, 0.0, MAPPED_MAX) - inputs) * masks).reshape(len(inputs), -1).sum(1)
    return float((error / (np.abs(inputs) * masks).reshape(len(inputs), -1).sum(1)).mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("-o", "--output", type=Path, default=Path("reports/rd-study/basis.json"))
    args = parser.parse_args()
    with BrdfDataset(args.dataset) as dataset:
        train, held = dataset.indices("train"), dataset.indices("validation")
        x_train, m_train = dataset.inputs(train), dataset.input_masks(train)
        x_held, m_held = dataset.inputs(held), dataset.input_masks(held)
    encoder = BrdfEncoder(effort=0)
    decoder = encoder.decoder

    def refined(x: np.ndarray, m: np.ndarray) -> np.ndarray:
        mu = np.stack([r.mu for r in encoder.encode_arrays([f"m{i}" for i in range(len(x))], x, m, [None] * len(x))])
        return np.concatenate([refine_latent(decoder.network, mu[i : i + 8], x[i : i + 8], m[i : i + 8], 3)
                               for i in range(0, len(x), 8)])

    start = time.perf_counter()
    z_train, z_held = refined(x_train, m_train), refined(x_held, m_held)
    base_train, base_held = decoder.decode_mapped(z_train), decoder.decode_mapped(z_held)
    valid = np.flatnonzero(m_train.reshape(len(train), -1).all(axis=0))
    flat = x_train.reshape(len(train), -1)[:, valid].astype(np.float64)
    mean = flat.mean(axis=0)
    data_basis = np.linalg.svd(flat - mean, full_matrices=False)[2]
    residual_train = ((x_train - base_train) * m_train).reshape(len(train), -1)[:, valid].astype(np.float64)
    residual_basis = np.linalg.svd(residual_train, full_matrices=False)[2]
    held_flat = x_held.reshape(len(held), -1)[:, valid].astype(np.float64)
    held_residual = ((x_held - base_held) * m_held).reshape(len(held), -1)[:, valid].astype(np.float64)

    def placed(values: np.ndarray, offset: np.ndarray | float = 0.0) -> np.ndarray:
        out = np.zeros((len(values), x_held[0].size))
        out[:, valid] = values
        return out.reshape(x_held.shape) + offset

    rows = [{"k": 0, "base": kept_slice_relae(base_held, x_held, m_held)}]
    for k in COUNTS:
        row: dict[str, float | int] = {"k": k}
        p = data_basis[:k]
        row["pca"] = kept_slice_relae(placed(mean + (held_flat - mean) @ p.T @ p), x_held, m_held)
        row["base+data"] = kept_slice_relae(placed(held_residual @ p.T @ p, base_held), x_held, m_held)
        q = residual_basis[:k]
        row["base+residual"] = kept_slice_relae(placed(held_residual @ q.T @ q, base_held), x_held, m_held)
        codes, coefficients = fit_basis_coefficients(decoder.network, z_held, x_held, m_held,
                                                     p.astype(np.float32), valid, 3)
        joint = placed(coefficients @ p, decoder.decode_mapped(codes))
        row["base+data joint"] = kept_slice_relae(joint, x_held, m_held)
        rows.append(row)
        print(json.dumps({key: round(v, 5) if isinstance(v, float) else v for key, v in row.items()}), flush=True)
    result = {"dataset": str(args.dataset), "held_out": len(held), "train": len(train),
              "metric": "kept-slice mapped RelAE, held-out mean", "seconds": time.perf_counter() - start,
              "rows": rows}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    torch.set_num_threads(max(1, torch.get_num_threads()))
    main()
