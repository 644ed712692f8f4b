"""Does the posterior width σ say how certain an encoding is? (issue 41, part 3)

For every material of a dataset, the encoder's posterior N(μ, σ²) and the
error of the decode at μ (mapped L1 per valid entry of the network input) are
measured. If σ meant something it would grow with the error, and be larger on
materials the model never saw than on its training materials. The rows give
per material σ's median and mean log σ and the error, per group (family ×
stored split) their medians, and the Spearman rank correlation of mean log σ
with the error, with a permutation p-value.

Examples
--------
>>> rank_correlation([1.0, 2.0, 3.0, 4.0], [10.0, 20.0, 30.0, 40.0])
1.0
>>> rank_correlation([1.0, 2.0, 3.0, 4.0], [4.0, 3.0, 2.0, 1.0])
-1.0
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["permutation_p_value", "posterior_width_rows", "rank_correlation"]


def _ranks(values: npt.ArrayLike) -> np.ndarray:
    """Ranks 0…n−1, ties sharing their mean rank."""
    array = np.asarray(values, dtype=np.float64)
    order = np.argsort(array, kind="stable")
    ranks = np.empty(len(array))
    ranks[order] = np.arange(len(array))
    for value in np.unique(array):
        tied = array == value
        ranks[tied] = ranks[tied].mean()
    return ranks


def rank_correlation(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Spearman's ρ: the Pearson correlation of the ranks (ties at their mean rank), in [−1, 1]."""
    ra, rb = _ranks(a), _ranks(b)
    ra, rb = ra - ra.mean(), rb - rb.mean()
    denominator = float(np.sqrt((ra**2).sum() * (rb**2).sum()))
    return float((ra * rb).sum() / denominator) if denominator > 0 else 0.0


def permutation_p_value(a: npt.ArrayLike, b: npt.ArrayLike, *, permutations: int = 2000, seed: int = 0) -> float:
    """Two-sided p-value of :func:`rank_correlation` against random pairings (``permutations`` draws, seeded)."""
    rng = np.random.default_rng(seed)
    observed = abs(rank_correlation(a, b))
    b_array = np.asarray(b, dtype=np.float64)
    hits = sum(abs(rank_correlation(a, rng.permutation(b_array))) >= observed for _ in range(permutations))
    return (hits + 1) / (permutations + 1)


def posterior_width_rows(model: str | os.PathLike[str] | None, dataset: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Rows of σ against the decode error for every material of a dataset.

    Parameters
    ----------
    model : path-like or str, optional
        Model folder, model name or decoder SHA-256 (default: the shipped model).
    dataset : path-like
        An HDF5 dataset (``bvae dataset build``) with inputs and masks.

    Returns
    -------
    list of dict
        One row per material (``code`` "material"), one per group (``code`` "group"), and one ``code``
        "summary" row with the rank correlation over all materials and over those outside the training split.
    """
    from brdfcodec.codec import BrdfEncoder
    from brdfcodec.datasets.hdf5 import BrdfDataset

    encoder = BrdfEncoder(model, effort=0)
    with BrdfDataset(dataset) as data:
        names, families, splits = list(data.names), list(data.families), list(data.split)
        inputs, masks = data.inputs(), data.input_masks()
    mu, sigma = encoder.posterior_from_inputs(inputs)
    decoded = encoder.decoder.decode_mapped(mu)
    errors = np.array([float(np.abs(decoded[i] - inputs[i])[masks[i]].mean()) for i in range(len(names))])
    log_sigma = np.log(sigma.astype(np.float64)).mean(axis=1)
    manifest = encoder.decoder.manifest
    context = {"model": manifest.name if manifest is not None else None,
               "decoder_sha256": encoder.decoder.reference.sha256 if encoder.decoder.reference else None,
               "dataset": os.fspath(dataset)}
    rows: list[dict[str, Any]] = []
    for i, name in enumerate(names):
        rows.append({**context, "code": "material", "material": name, "family": families[i], "split": splits[i],
                     "sigma_median": float(np.median(sigma[i])), "mean_log_sigma": float(log_sigma[i]),
                     "l1_mapped": float(errors[i])})
    groups = sorted({(f, s) for f, s in zip(families, splits, strict=True)})
    for family, split in groups:
        chosen = [i for i in range(len(names)) if families[i] == family and splits[i] == split]
        rows.append({**context, "code": "group", "family": family, "split": split, "materials": len(chosen),
                     "sigma_median": float(np.median(sigma[chosen])),
                     "mean_log_sigma": float(log_sigma[chosen].mean()),
                     "l1_mapped_mean": float(errors[chosen].mean())})
    outside = [i for i in range(len(names)) if splits[i] != "train"]
    summary: dict[str, Any] = {**context, "code": "summary", "materials": len(names),
                               "spearman_all": rank_correlation(log_sigma, errors),
                               "p_all": permutation_p_value(log_sigma, errors)}
    if len(outside) >= 3:
        summary["spearman_outside_training_split"] = rank_correlation(log_sigma[outside], errors[outside])
        summary["p_outside_training_split"] = permutation_p_value(log_sigma[outside], errors[outside])
    rows.append(summary)
    return rows


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """The group rows and the summary as text."""
    lines = [f"{'family':8} {'split':10} {'n':>3} {'σ median':>9} {'mean log σ':>10} {'L1/entry':>9}"]
    for row in rows:
        if row["code"] == "group":
            lines.append(f"{row['family']:8} {row['split']:10} {row['materials']:3d} {row['sigma_median']:9.5f} "
                         f"{row['mean_log_sigma']:10.3f} {row['l1_mapped_mean']:9.4f}")
    for row in rows:
        if row["code"] == "summary":
            text = f"Spearman(mean log σ, L1): all {row['spearman_all']:+.3f} (p {row['p_all']:.3f})"
            if "spearman_outside_training_split" in row:
                text += (f"; outside the training split {row['spearman_outside_training_split']:+.3f} "
                         f"(p {row['p_outside_training_split']:.3f})")
            lines.append(text)
    return "\n".join(lines)
