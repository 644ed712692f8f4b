"""What storing a compact base's μ on the fixed grid (μ = q / 32, no step) buys at small size budgets (issue 14).

Usage::

    python benchmarks/compact_mu_study.py DATASET.h5 [-o reports/rd-study/compact-mu.json]

Encodes the dataset's held-out (validation) materials with the default model
at small size budgets (``BrdfEncoder(bytes=N)``, effort 1, float16 latents),
once as the encoder does (a compact μ on the fixed grid where it fits ±3.97,
``layers.mu = "int8-fixed"``: 9 bytes of base for D = 8) and once with every
compact μ on its own float16 step (``"int8"``: 11 bytes, the only compact
form before format 1.5), and records the mean full-table mapped RelAE,
payloads and coefficient counts of each.
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np

# sibling script: Python puts the running script's folder on sys.path
from basis_study import held_out_materials, replaced, study_arguments

import brdfcodec.codec.rate as rate
from brdfcodec.codec import BrdfEncoder
from brdfcodec.format.layered_record import MU_INT8, LayeredRecord
from brdfcodec.representation.metrics import error_report

BUDGETS = (16, 24, 32, 64)


def main() -> None:
    args = study_arguments(__doc__, "reports/rd-study/compact-mu.json")
    start = time.perf_counter()
    held = held_out_materials(args.dataset)
    rows: list[dict[str, Any]] = []
    for budget in BUDGETS:
        for label, own_step in (("fixed grid where mu fits (encoder)", False), ("own float16 step", True)):
            encoder = BrdfEncoder(bytes=budget, latent_dtype="float16", effort=1)
            with replaced(rate, "compact_mu_storage", lambda mu: MU_INT8, active=own_step):
                records = encoder.encode_arrays(held.names, held.inputs, held.masks, held.tables)
            layered = [r for r in records if isinstance(r, LayeredRecord)]
            errors = [error_report(t.values, encoder.decoder.decode(r, masked="keep").astype(np.float64),
                                   t.mask).relae_mapped.overall for r, t in zip(records, held.tables, strict=True)]
            rows.append({
                "budget": budget, "policy": label,
                "relae_mapped_mean": float(np.mean(errors)),
                "payload_bytes_mean": float(np.mean([r.meta["rate"]["payload_bytes"] for r in records])),
                "basis_counts": sorted({r.basis.count for r in layered if r.basis is not None}),
                "fixed_grid_records": sum(r.fixed_mu_grid for r in layered),
            })
            print(json.dumps(rows[-1]), flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({
        "data": held.description, "materials": held.names, "effort": 1, "latent_dtype": "float16",
        "metric": "full-table mapped RelAE, held-out mean",
        "command": f"python benchmarks/compact_mu_study.py {args.dataset}",
        "rows": rows, "seconds": time.perf_counter() - start,
    }, indent=1) + "\n")


if __name__ == "__main__":
    main()
