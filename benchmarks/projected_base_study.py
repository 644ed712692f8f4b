"""What projecting a layered record's base decode on the shared basis gains (format 1.6, issue 14).

Usage::

    python benchmarks/projected_base_study.py DATASET.h5 [-o reports/rd-study/projected-base.json]

The shipped model's encoder at effort 1 with float16 latents, under size
budgets of 16, 32, 64 and 128 bytes, with the base decode projected on the
shared basis' first P vectors around the decoder's linear-path mean
(``layers.basis.project``; P = 0: not projected). Full-table mapped RelAE
over valid entries, mean over the dataset's held-out (validation) materials
and over every fourth training material.
"""

from __future__ import annotations

import json
import time

import numpy as np
from basis_study import HeldOut, held_out_materials, replaced, study_arguments

import brdfcodec.codec.encoding as encoding
from brdfcodec.codec import BrdfEncoder
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.representation.metrics import error_report

BUDGETS = (16, 32, 64, 128)
VECTORS = (0, 25, 50, 75)


def training_materials(path) -> HeldOut:
    """Every fourth material of the training split, with its full table."""
    with BrdfDataset(path) as dataset:
        rows = dataset.indices("train")[::4]
        return HeldOut(dataset.inputs(rows), dataset.input_masks(rows), [dataset.table(i) for i in rows],
                       [dataset.names[i] for i in rows], dataset.description)


def main() -> None:
    args = study_arguments(__doc__, "reports/rd-study/projected-base.json")
    start = time.perf_counter()
    rows = []
    splits = (("held-out", held_out_materials(args.dataset)), ("train", training_materials(args.dataset)))
    for split, materials in splits:
        for vectors in VECTORS:
            for budget in BUDGETS:
                encoder = BrdfEncoder(bytes=budget, latent_dtype="float16", effort=1, project_base=vectors > 0)
                with replaced(encoding, "PROJECTED_BASE_VECTORS", vectors, active=vectors > 0):
                    records = encoder.encode_arrays(materials.names, materials.inputs, materials.masks,
                                                    materials.tables)
                decoded = [encoder.decoder.decode(r, masked="keep").astype(np.float64) for r in records]
                errors = [error_report(t.values, d, t.mask).relae_mapped.overall
                          for d, t in zip(decoded, materials.tables, strict=True)]
                assert all(getattr(getattr(r, "basis", None), "project", 0) in (0, vectors) for r in records)
                rows.append({"split": split, "materials": len(records), "budget": budget, "project": vectors,
                             "mapped_relae": float(np.mean(errors)),
                             "payload_bytes": float(np.mean([r.meta["rate"]["payload_bytes"] for r in records]))})
                print(json.dumps(rows[-1]), flush=True)
    result = {"dataset": str(args.dataset), "metric": "full-table mapped RelAE, mean over materials",
              "encoder": "shipped model, effort 1, float16 latents", "seconds": time.perf_counter() - start,
              "rows": rows}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
