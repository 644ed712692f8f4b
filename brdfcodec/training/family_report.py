"""A model measured per measurement family and split, beside PCA baselines (issue 12, item 6).

:func:`evaluate_by_family` encodes every material of a dataset with an
exported model (at a chosen refinement effort, base latent only), decodes
it, and reports per (family, split): mapped and linear RelAE
(``spec/conventions.md`` §8) and ΔE ITP of the report's 64² sphere render
under a directional light (:func:`~brdfcodec.report.evaluate.comparison_render`),
for the model and for PCA-8 and PCA-16 fitted on the *model's own*
training materials (those of the dataset named in the model's
``info.data.train``), so that a family the model never saw is unseen by the
baselines too — or on the dataset's own training split when the model was
trained on 16 or fewer of its materials (another database altogether).

A row's ``split`` is relative to the model: ``train`` for the materials it
was trained on, ``held-out`` for every other material of the dataset.

With ``mu_grid`` g, μ is rounded to the grid 2^−g before it is decoded — the
latent as a record's coded μ stores it (``spec/bvae-format.md`` §4.9) — and
each row also says how many bytes that μ takes coded alone under the
format's unit prior (its termination included), and how many it would take
under per-dimension priors fitted to the model's training materials
(:func:`~brdfcodec.layers.coded_basis.fit_prior_codes` on their μ on the
same grid; ``mu_prior_codes``, the fitted codes, where the format's unit
prior is 16·g): what a model-level prior for μ would save, measured on
materials the fit did not see.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.format.records import LatentRecord
from brdfcodec.layers.coded_basis import coded_mu_codes, encode_integers, fit_prior_codes
from brdfcodec.models.pca import fit_pca
from brdfcodec.render.image_metrics import compare_images
from brdfcodec.report.evaluate import comparison_render
from brdfcodec.representation import table_from_network_output
from brdfcodec.representation.metrics import error_report

__all__ = ["FamilyRow", "evaluate_by_family", "family_table"]

#: PCA sizes of the baselines.
PCA_SIZES = (8, 16)


@dataclass(frozen=True)
class FamilyRow:
    """Means over the materials of one family and split (RelAE dimensionless, ΔE ITP in ΔE ITP units)."""

    family: str
    split: str
    count: int
    mapped: float
    linear: float
    delta_e_itp: float
    pca8_mapped: float
    pca16_mapped: float
    pca8_delta_e_itp: float
    pca16_delta_e_itp: float
    worst: str
    mu_grid: int | None = None
    mu_bytes: float | None = None
    #: μ's bytes coded alone under the per-dimension prior codes fitted to the training materials' μ, mean over
    #: the group's materials, bytes (None: no grid, or no training material in the dataset to fit them to).
    mu_bytes_fitted: float | None = None
    #: Those fitted prior codes, one per latent dimension (the format's unit prior: 16·mu_grid each).
    mu_prior_codes: tuple[int, ...] | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return asdict(self)


def evaluate_by_family(
    model: str | os.PathLike[str] | None, dataset_path: str | os.PathLike[str], *, effort: int = 0,
    limit: int | None = None, mu_grid: int | None = None,
) -> list[FamilyRow]:
    """Measure a model and its PCA baselines on every material of a dataset, grouped by family and split.

    Parameters
    ----------
    model : path or None
        Model folder (None: the shipped default).
    dataset_path : path
        A ``bvae dataset build`` file; its families group the rows.
    effort : int, default 0
        Refinement effort of the encoder (0–3).
    limit : int, optional
        Only the first ``limit`` materials of each family and split (for tests).
    mu_grid : int, optional
        Decode μ rounded to the grid 2^−``mu_grid`` (1 to 5), as a coded μ
        stores it, and report its coded bytes (under the unit prior, and
        under per-dimension priors fitted to the training materials' μ);
        None (the default) decodes μ as the encoder gives it.
    """
    from brdfcodec.codec import BrdfEncoder

    if mu_grid is not None and not 1 <= mu_grid <= 5:
        raise ValueError(f"mu_grid must be from 1 to 5, got {mu_grid}")

    encoder = BrdfEncoder(model, effort=effort)
    decoder = encoder.decoder
    trained_on = set(encoder.manifest.info.get("data", {}).get("train", [])) if encoder.manifest else set()
    per_material: list[dict[str, Any]] = []
    with BrdfDataset(dataset_path) as dataset:
        names = list(dataset.names)
        trained = {i for i, n in enumerate(names) if n in trained_on}
        # The baselines learn from what the model learnt from; from the dataset's own training split when the
        # model was trained on too few of its materials (none, for another database).
        pca_rows = sorted(trained) if len(trained) > max(PCA_SIZES) else dataset.indices("train")
        bases = {k: fit_pca(dataset.inputs(pca_rows), min(k, len(pca_rows))) for k in PCA_SIZES}
        groups: dict[tuple[str, str], list[int]] = {}
        for i in range(len(names)):
            groups.setdefault((dataset.families[i], "train" if i in trained else "held-out"), []).append(i)
        chosen = sorted(i for rows in groups.values() for i in rows[: limit or len(rows)])
        for i in chosen:
            reference = dataset.table(i)
            inputs, masks = dataset.inputs([i]), dataset.input_masks([i])
            record = encoder.encode_arrays([names[i]], inputs, masks, [None])[0]
            mu_bytes, integers = None, None
            if mu_grid is not None:
                record, mu_bytes, integers = _on_grid(record, mu_grid)
            estimates = {"model": decoder.decode(record, masked="keep").astype(np.float64)}
            for k, basis in bases.items():
                mapped = basis.decode(basis.encode(inputs))[0]
                estimates[f"pca{k}"] = table_from_network_output(mapped).astype(np.float64)
            image = comparison_render(reference.values, reference.mask)
            row: dict[str, Any] = {"name": names[i], "family": dataset.families[i],
                                   "split": "train" if i in trained else "held-out", "mu_bytes": mu_bytes,
                                   "mu_integers": integers}
            for label, table in estimates.items():
                report = error_report(reference.values, table, reference.mask)
                row[f"{label}_mapped"] = report.relae_mapped.overall
                row[f"{label}_linear"] = report.relae_linear.overall
                row[f"{label}_itp"] = compare_images(image, comparison_render(table, reference.mask)).delta_e_itp_mean
            per_material.append(row)
    return _group(per_material, mu_grid, _price_under_fitted_prior(per_material))


def _price_under_fitted_prior(rows: list[dict[str, Any]]) -> tuple[int, ...] | None:
    """Prior codes fitted to the μ integers of the training materials (the rows of split ``train``), and each
    row's ``mu_bytes_fitted``, its μ's bytes under them (the rows' ``mu_integers`` consumed); None, and no bytes,
    where μ was not put on a grid or no row is a training material."""
    fit_on = [r["mu_integers"] for r in rows if r["split"] == "train" and r["mu_integers"] is not None]
    codes = fit_prior_codes(np.stack(fit_on)) if fit_on else None
    for r in rows:
        integers = r.pop("mu_integers")
        r["mu_bytes_fitted"] = None if codes is None else float(len(encode_integers(integers, codes)))
    return None if codes is None else tuple(int(c) for c in codes)


def _group(rows: Sequence[dict[str, Any]], mu_grid: int | None = None,
           prior_codes: tuple[int, ...] | None = None) -> list[FamilyRow]:
    out = []
    for family in sorted({r["family"] for r in rows}):
        for split in ("train", "held-out"):
            chosen = [r for r in rows if r["family"] == family and r["split"] == split]
            if not chosen:
                continue

            def mean(key: str, chosen: list[dict[str, Any]] = chosen) -> float:
                return float(np.mean([r[key] for r in chosen]))

            worst = max(chosen, key=lambda r: r["model_mapped"])["name"]
            out.append(FamilyRow(family, split, len(chosen), mean("model_mapped"), mean("model_linear"),
                                 mean("model_itp"), mean("pca8_mapped"), mean("pca16_mapped"), mean("pca8_itp"),
                                 mean("pca16_itp"), worst, mu_grid, None if mu_grid is None else mean("mu_bytes"),
                                 None if prior_codes is None else mean("mu_bytes_fitted"), prior_codes))
    return out


def _on_grid(record: LatentRecord, grid: int) -> tuple[LatentRecord, float, npt.NDArray[np.int64]]:
    """The record with μ rounded to the grid 2^−grid, the bytes of that μ coded alone (§4.9's prior), and its
    integers."""
    step = 2.0**-grid
    q = np.round(record.mu.astype(np.float64) / step).astype(np.int64)
    size = len(encode_integers(q, coded_mu_codes(grid, q.size)))
    return replace(record, mu=(q * step).astype(np.float32)), float(size), q


def family_table(rows: Sequence[FamilyRow | dict[str, Any]]) -> list[str]:
    """Markdown table of :func:`evaluate_by_family` rows (for the model card and the CLI)."""
    lines = [
        "| family | split | materials | mapped RelAE | linear RelAE | ΔE ITP | PCA-8 mapped | PCA-16 mapped "
        "| PCA-8 ΔE ITP | PCA-16 ΔE ITP | worst (mapped) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        r = row.as_dict() if isinstance(row, FamilyRow) else dict(row)
        lines.append(
            f"| {r['family']} | {r['split']} | {r['count']} | {r['mapped']:.4f} | {r['linear']:.4f} | "
            f"{r['delta_e_itp']:.3f} | {r['pca8_mapped']:.4f} | {r['pca16_mapped']:.4f} | "
            f"{r['pca8_delta_e_itp']:.3f} | {r['pca16_delta_e_itp']:.3f} | {r['worst']} |"
        )
    return lines
