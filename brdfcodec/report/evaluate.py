"""Evaluate operating points on a dataset: per-material errors and times, then one record per point."""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.render.image_metrics import compare_images
from brdfcodec.render.preview import MaterialTable, render_sphere
from brdfcodec.report.points import Material, OperatingPoint, standard_points
from brdfcodec.report.rd_points import rate_distortion_points
from brdfcodec.representation import map_values, reflectance_from_stored
from brdfcodec.representation.metrics import relae_between_mapped, relae_linear
from brdfcodec.version import __version__

__all__ = ["comparison_render", "environment", "evaluate_dataset", "summarise"]

_RENDER_SIZE = 64
_LIGHT = (-1.0, 1.0, 1.0)


def environment() -> dict[str, Any]:
    """Where the numbers were measured: device and versions."""
    import torch

    return {
        "device": f"cpu ({os.cpu_count()} cores, {torch.get_num_threads()} torch threads)",
        "platform": platform.platform(),
        "python": platform.python_version(),
        "brdfcodec": __version__,
        "torch": torch.__version__,
        "numpy": np.__version__,
    }


def comparison_render(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The report's ΔE render: a 64² sphere under a directional light of a table in stored units (valid entries)."""
    reflectance = reflectance_from_stored(np.where(mask, np.maximum(values, 0.0), 0.0))
    return render_sphere(MaterialTable(reflectance, mask), size=_RENDER_SIZE, light=_LIGHT)


def _measure(
    point: OperatingPoint, material: Material, mapped_reference: np.ndarray, reference_image: np.ndarray
) -> dict[str, Any]:
    start = time.perf_counter()
    payload = point.encode(material)
    encoded = time.perf_counter()
    estimate = point.decode(payload)
    decoded = time.perf_counter()
    estimate = np.nan_to_num(estimate, nan=0.0, posinf=0.0, neginf=0.0)
    valid = material.mask
    mapped_est = map_values(estimate)
    image = compare_images(reference_image, comparison_render(estimate, valid))
    return {
        "material": material.name,
        "split": material.split,
        "bytes": point.payload_bytes(payload),
        "encode_s": encoded - start,
        "decode_s": decoded - encoded,
        "relae_mapped": relae_between_mapped(mapped_reference, mapped_est, valid).overall,
        "relae_linear": relae_linear(material.values, estimate, valid).overall,
        "log_domain_mae": float(np.abs(mapped_est - mapped_reference)[valid].mean()),
        "delta_e_itp": image.delta_e_itp_mean,
        "delta_e_2000": image.delta_e_2000_mean,
        "psnr_db": image.psnr_db,
    }


def evaluate_dataset(
    dataset_path: str | os.PathLike[str],
    *,
    points: Sequence[OperatingPoint] | None = None,
    pca_sizes: Sequence[int] = (8, 16, 32),
    extra_models: Sequence[str | os.PathLike[str]] = (),
    limit: int | None = None,
    progress: bool = True,
) -> tuple[list[OperatingPoint], list[dict[str, Any]], dict[str, Any]]:
    """Run every operating point on every material of a dataset (with full tables).

    Returns
    -------
    points : list of OperatingPoint
    rows : list of dict
        One per (point, material): bytes, times, RelAE (mapped, linear),
        log-domain error, ΔE ITP / 2000 and PSNR of a 64² sphere render.
    data : dict
        The dataset's description (kind, size, split).
    """
    with BrdfDataset(dataset_path) as dataset:
        if not dataset.has_tables:
            raise ValueError(f"{dataset_path}: the report needs full tables (build the dataset without --no-tables)")
        train = dataset.indices("train")
        indices = list(range(len(dataset)))[: limit or None]
        data = {
            "file": Path(dataset_path).name,
            "source_kind": dataset.source_kind,
            "description": dataset.description,
            "materials": len(indices),
            "train": sum(1 for i in indices if i in train),
            "validation": sum(1 for i in indices if i not in train),
        }
        if points is None:
            points = standard_points(dataset.inputs(train), pca_sizes, extra_models)
            points += rate_distortion_points(dataset.inputs(train))
        rows: list[dict[str, Any]] = []
        for index in tqdm(indices, desc="report", unit="material", disable=not progress or None):
            brdf = dataset.table(index)
            material = Material(
                name=dataset.names[index],
                values=brdf.values,
                mask=brdf.mask,
                inputs=dataset.inputs([index])[0],
                split="train" if index in train else "validation",
            )
            reference_image = comparison_render(material.values, material.mask)
            mapped_reference = map_values(material.values)  # once per material, shared by every point
            for point in points:
                if material.split == "train" and getattr(point, "held_out_only", False):  # issue 14 RD points
                    continue
                rows.append({"point": point.name, **_measure(point, material, mapped_reference, reference_image)})
    return list(points), rows, data


def _stats(values: list[float]) -> dict[str, float]:
    array = np.asarray(values, dtype=np.float64)
    return {
        "mean": float(array.mean()),
        "median": float(np.median(array)),
        "p90": float(np.percentile(array, 90)),
        "worst": float(array.max()),
    }


def summarise(
    points: Sequence[OperatingPoint], rows: Sequence[dict[str, Any]], data: dict[str, Any]
) -> list[dict[str, Any]]:
    """One JSON-ready record per operating point: what it is, its sizes, median times and errors per split
    (documentation: Results)."""
    env = environment()
    records = []
    for point in points:
        mine = [r for r in rows if r["point"] == point.name]
        by_split: dict[str, Any] = {}
        for split in ("validation", "train", "all"):
            chosen = [r for r in mine if split == "all" or r["split"] == split]
            if not chosen:
                continue
            worst = max(chosen, key=lambda r: r["relae_mapped"])
            by_split[split] = {
                "materials": len(chosen),
                "relae_mapped": {**_stats([r["relae_mapped"] for r in chosen]), "worst_material": worst["material"]},
                "relae_linear": _stats([r["relae_linear"] for r in chosen]),
                "log_domain_mae": _stats([r["log_domain_mae"] for r in chosen]),
                "delta_e_itp": _stats([r["delta_e_itp"] for r in chosen]),
                "delta_e_2000": _stats([r["delta_e_2000"] for r in chosen]),
            }
        records.append({
            "name": point.name,
            "family": getattr(point, "family", point.name),  # issue 14: one rate–distortion curve per family
            "held_out_only": getattr(point, "held_out_only", False),
            "description": point.description,
            "lossless": point.lossless,
            "data": data,
            "bytes_per_material": float(np.mean([r["bytes"] for r in mine])),
            "shared_bytes": point.shared_bytes(),
            "encode_ms_median": 1e3 * float(np.median([r["encode_s"] for r in mine])),
            "decode_ms_median": 1e3 * float(np.median([r["decode_s"] for r in mine])),
            "errors": by_split,
            **env,
        })
    return records
