"""Measure the edge-slot floor: what the kept slots below the horizon cost a decoded table on the horizon band.

usage (repository root; the dataset built as docs/results.md says, "The shipped model on materials it never saw"):

    python reports/edge-slots/edge_slot_rows.py [--dataset runs/v3-held-out.h5] [--budgets 64,1024,16384]
    python reports/edge-slots/edge_slot_rows.py --models MODEL ... [--models-dataset runs/both.h5]

Two studies, one rows file (``reports/edge-slots/edge-slots.jsonl``) and its report (``edge-slots.txt``):

- ``edge-slot-floor``, every material of the dataset: a material's own kept slices interpolated back to 180 φd
  bins, with 0 at the kept slots that are not valid (the network input) and with the edge slots' fitted values
  (:func:`brdfcodec.representation.edge_slots.edge_slot_targets`), and with every slot that is not valid filled
  from its cell's nearest valid slot (:func:`nearest_valid_fill`: what a decode-time rule could do), in mapped
  RelAE over the valid bins; and the share of the valid bins on the horizon band (a valid bin whose two kept
  neighbours are not both valid).
- ``edge-slot-share``, the seven materials of the shipped model's held-out rows (six random analytic materials and
  the real RGL measurement): each compressed with ``bvae compress``'s defaults at each budget (the library's
  ``BrdfEncoder(bytes=N)``), decoded, and its mapped RelAE split into the horizon band's part and the rest's
  (both over the sum of all valid bins' reference values, so that they add up).
- ``edge-slot-models`` (with ``--models``, into ``edge-slot-models.jsonl``): for each model folder, the materials
  its manifest holds out, encoded at effort 0 (the encoder's μ, no layer) and decoded, the same split per
  material: what a model trained with ``bvae train --edge-slots`` removes of the horizon band's part.
"""

from __future__ import annotations

import argparse
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.report.rows import read_rows, stamp, write_rows
from brdfcodec.representation.edge_slots import edge_slot_targets
from brdfcodec.representation.layout import (
    from_network_layout,
    interpolate_slices,
    interpolation_plan,
    select_kept_slices,
)
from brdfcodec.representation.mapping import map_values
from brdfcodec.representation.network_io import network_input_from_table

FOLDER = Path("reports/edge-slots")
#: The shipped model's held-out rows' materials (docs/results.md): the first six random analytic ones and the
#: real RGL measurement.
SHARE_MATERIALS = ("analytic-000", "analytic-001", "analytic-002", "analytic-003", "analytic-004", "analytic-005",
                   "paper_white")


def _mapped(table: MerlBRDF) -> np.ndarray:
    return map_values(np.where(table.mask, table.values, 0.0))


def _horizon_band(table: MerlBRDF) -> np.ndarray:
    """Valid bins whose two kept neighbours (the interpolation's) are not both valid."""
    left, right, _ = interpolation_plan()
    kept_valid = select_kept_slices(table.mask)
    return table.mask & ~(kept_valid[..., left] & kept_valid[..., right])


def nearest_valid_fill(kept: np.ndarray, kept_valid: np.ndarray) -> np.ndarray:
    """Kept slices (..., 21) with each slot that is not valid set to its cell's nearest valid slot's value (the
    mean of the two where valid slots lie at equal distance on both sides; unchanged in a cell with none): what
    a decode-time fill could do, measured here, not part of the format."""
    slots = np.arange(kept.shape[-1])
    left = np.maximum.accumulate(np.where(kept_valid, slots, -1), axis=-1)
    right = np.flip(np.minimum.accumulate(np.flip(np.where(kept_valid, slots, kept.shape[-1]), -1), axis=-1), -1)
    has_left, has_right = left >= 0, right < kept.shape[-1]
    value_left = np.take_along_axis(kept, np.clip(left, 0, kept.shape[-1] - 1), axis=-1)
    value_right = np.take_along_axis(kept, np.clip(right, 0, kept.shape[-1] - 1), axis=-1)
    distance_left, distance_right = slots - left, right - slots
    both = has_left & has_right
    fill = np.where(both & (distance_left < distance_right), value_left,
                    np.where(both & (distance_right < distance_left), value_right,
                             np.where(both, 0.5 * (value_left + value_right),
                                      np.where(has_left, value_left, np.where(has_right, value_right, kept)))))
    return np.where(kept_valid, kept, fill)


def floor_row(name: str, family: str, table: MerlBRDF) -> dict[str, Any]:
    """One material's interpolation floors, zero and fitted edge slots."""
    mapped = _mapped(table)
    inputs, _ = network_input_from_table(table.values, table.mask)
    targets, weights = edge_slot_targets(table.values, table.mask)
    magnitude = float(np.abs(mapped)[table.mask].sum())

    def relae(kept: np.ndarray) -> float:
        estimate = interpolate_slices(from_network_layout(kept).astype(np.float64))
        return float(np.abs(estimate - mapped)[table.mask].sum()) / magnitude

    band = _horizon_band(table)
    return {"material": name, "family": family, "valid_bins": int(table.mask.sum()),
            "horizon_band_share": float(band.sum() / table.mask.sum()), "edge_slots": int((weights > 0).sum()),
            "floor_zero": relae(inputs), "floor_edge_slots": relae(np.where(weights > 0, targets, inputs)),
            "floor_nearest_valid": relae(nearest_valid_fill(inputs.reshape(3, 21, 90, 90).transpose(0, 2, 3, 1),
                                                            select_kept_slices(table.mask))
                                         .transpose(0, 3, 1, 2).reshape(inputs.shape))}


def share_rows(dataset: BrdfDataset, budgets: Sequence[int]) -> list[dict[str, Any]]:
    """The shipped model's decoded error at each budget, split into the horizon band's part and the rest's."""
    decoder = BrdfDecoder()
    rows = []
    for name in SHARE_MATERIALS:
        index = dataset.names.index(name)
        table = dataset.table(index)
        mapped = _mapped(table)
        band = _horizon_band(table)
        magnitude = float(np.abs(mapped)[table.mask].sum())
        for budget in budgets:
            record = BrdfEncoder(bytes=budget).encode(table, name=name)
            decoded = decoder.decode(record)
            error = np.abs(_mapped(MerlBRDF(np.maximum(decoded.astype(np.float64), 0.0), name=name)) - mapped)
            rows.append({"material": name, "family": dataset.families[index], "budget": budget,
                         "model": decoder.manifest.name, "record_bytes": int(record.meta["rate"]["record_bytes"]),
                         "relae_mapped": float(error[table.mask].sum()) / magnitude,
                         "horizon_band_part": float(error[band].sum()) / magnitude,
                         "rest_part": float(error[table.mask & ~band].sum()) / magnitude})
    return rows


def model_rows(models: Sequence[str], dataset_path: str) -> list[dict[str, Any]]:
    """Each model's held-out materials at effort 0, the decoded mapped RelAE split as :func:`share_rows`'s."""
    from brdfcodec.models.store import load_manifest

    rows = []
    with BrdfDataset(dataset_path) as dataset:
        for folder in models:
            manifest = load_manifest(folder)
            held = set(manifest.info.get("data", {}).get("validation", []))
            encoder, decoder = BrdfEncoder(folder, effort=0), BrdfDecoder(folder)
            for index in [i for i, name in enumerate(dataset.names) if name in held]:
                table = dataset.table(index)
                mapped = _mapped(table)
                band = _horizon_band(table)
                magnitude = float(np.abs(mapped)[table.mask].sum())
                decoded = decoder.decode(encoder.encode(table, name=dataset.names[index]))
                error = np.abs(_mapped(MerlBRDF(np.maximum(decoded.astype(np.float64), 0.0))) - mapped)
                rows.append({"model": manifest.name, "model_folder": str(folder), "material": dataset.names[index],
                             "family": dataset.families[index], "effort": 0,
                             "relae_mapped": float(error[table.mask].sum()) / magnitude,
                             "horizon_band_part": float(error[band].sum()) / magnitude,
                             "rest_part": float(error[table.mask & ~band].sum()) / magnitude})
    return rows


def models_text(rows: Sequence[dict[str, Any]]) -> str:
    """Per model and family: mean mapped RelAE at effort 0 and the horizon band's part of it."""
    lines = ["# edge-slot-models: held-out materials at effort 0, mapped RelAE and the horizon band's part",
             f"# commit {rows[0]['commit']}, dataset {rows[0]['dataset']}; rows: edge-slot-models.jsonl", "",
             "| model | family | materials | mapped RelAE | horizon band's part | rest |",
             "|---|---|---:|---:|---:|---:|"]
    for model in dict.fromkeys(row["model"] for row in rows):
        for family in sorted({row["family"] for row in rows if row["model"] == model}):
            part = [row for row in rows if row["model"] == model and row["family"] == family]
            mean = {key: statistics.fmean(row[key] for row in part)
                    for key in ("relae_mapped", "horizon_band_part", "rest_part")}
            lines.append(f"| {model} | {family} | {len(part)} | {mean['relae_mapped']:.4f} | "
                         f"{mean['horizon_band_part']:.4f} | {mean['rest_part']:.4f} |")
    return "\n".join(lines) + "\n"


def text(rows: Sequence[dict[str, Any]]) -> str:
    """The report: floors per family (median, range), then the decoded errors' split per budget and material."""
    lines = [__doc__.split("\n\n")[0], "",
             f"# commit {rows[0]['commit']}, dataset {rows[0]['dataset']}; rows: edge-slots.jsonl", "",
             "## edge-slot-floor: a material's own kept slices interpolated (mapped RelAE over valid bins)", "",
             "| family | materials | horizon band share of valid bins | 0 at the slots below the horizon | "
             "edge slots fitted | slots below the horizon filled from the nearest valid one |",
             "|---|---:|---:|---:|---:|---:|"]
    floors = [row for row in rows if row["study"] == "edge-slot-floor"]
    for family in sorted({row["family"] for row in floors}):
        part = [row for row in floors if row["family"] == family]

        def spread(key: str, part: list[dict[str, Any]] = part) -> str:
            values = [row[key] for row in part]
            return f"{statistics.median(values):.4f} ({min(values):.4f}–{max(values):.4f})"

        lines.append(f"| {family} | {len(part)} | {spread('horizon_band_share')} | {spread('floor_zero')} | "
                     f"{spread('floor_edge_slots')} | {spread('floor_nearest_valid')} |")
    lines += ["", "Median (range) over the family's materials.", "",
              "## edge-slot-share: the shipped model's records decoded, mapped RelAE and the horizon band's part", "",
              "| material | family | budget | record bytes | mapped RelAE | horizon band's part | rest |",
              "|---|---|---:|---:|---:|---:|---:|"]
    for row in (row for row in rows if row["study"] == "edge-slot-share"):
        lines.append(f"| {row['material']} | {row['family']} | {row['budget']} | {row['record_bytes']} | "
                     f"{row['relae_mapped']:.4f} | {row['horizon_band_part']:.4f} | {row['rest_part']:.4f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="runs/v3-held-out.h5", help="dataset with full tables")
    parser.add_argument("--budgets", default="64,1024,16384", help="budgets of the decoded split (bytes)")
    parser.add_argument("--report-only", action="store_true", help="write the report from the committed rows")
    parser.add_argument("--models", nargs="+", help="model folders: the edge-slot-models study instead")
    parser.add_argument("--models-dataset", default="runs/both.h5", help="the models' dataset (their held-out)")
    args = parser.parse_args()
    if args.models:
        out = FOLDER / "edge-slot-models.jsonl"
        rows = (read_rows(out) if args.report_only else
                stamp(model_rows(args.models, args.models_dataset), study="edge-slot-models",
                      dataset=args.models_dataset))
        if not args.report_only:
            write_rows(out, rows)
        (FOLDER / "edge-slot-models.txt").write_text(models_text(rows), encoding="utf-8")
        print(f"wrote {out} ({len(rows)} rows) and edge-slot-models.txt")
        return
    out = FOLDER / "edge-slots.jsonl"
    if args.report_only:
        rows = read_rows(out)
    else:
        budgets = [int(b) for b in args.budgets.split(",")]
        with BrdfDataset(args.dataset) as dataset:
            floors = [floor_row(name, dataset.families[i], dataset.table(i)) for i, name in enumerate(dataset.names)]
            shares = share_rows(dataset, budgets)
        rows = (stamp(floors, study="edge-slot-floor", dataset=args.dataset)
                + stamp(shares, study="edge-slot-share", dataset=args.dataset))
        write_rows(out, rows)
    (FOLDER / "edge-slots.txt").write_text(text(rows), encoding="utf-8")
    print(f"wrote {out} ({len(rows)} rows) and edge-slots.txt")


if __name__ == "__main__":
    main()
