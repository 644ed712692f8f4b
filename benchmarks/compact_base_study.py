"""What a compact base buys at small size budgets (issue 14).

Usage::

    python benchmarks/compact_base_study.py DATASET.h5 [-o reports/rd-study/compact-base.json]

Encodes the dataset's held-out (validation) materials with the default model
at small size budgets (``BrdfEncoder(bytes=N)``, effort 1, float16 latents),
once as the encoder does (a compact base — μ as int8 with a float16 step, σ
as one shared byte — where the budget cannot hold all the basis
coefficients beside μ in the latent dtype, :func:`~brdfcodec.codec.rate.compact_base_pays`)
and once with the base in the latent dtype (σ one byte per dimension), and
records the mean full-table mapped RelAE, payloads and coefficient counts of
each. It also records what the compact base costs on its own: the base
decode's error with μ as int8 against μ in float16, and how far the shared
σ is from the per-dimension widths.
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
from brdfcodec.layers.basis import int8_with_step
from brdfcodec.format.layered_record import LayeredRecord, shared_sigma_code, sigma_from_codes
from brdfcodec.representation.metrics import error_report

BUDGETS = (16, 32, 64, 96)


def main() -> None:
    args = study_arguments(__doc__, "reports/rd-study/compact-base.json")
    start = time.perf_counter()
    held = held_out_materials(args.dataset)
    x, m, tables, names, description = held.inputs, held.masks, held.tables, held.names, held.description
    encoder = BrdfEncoder(latent_dtype="float16")
    decoder = encoder.decoder

    def relae(record: Any, table: Any) -> float:
        decoded = decoder.decode(record, masked="keep").astype(np.float64)
        return error_report(table.values, decoded, table.mask).relae_mapped.overall

    # The base alone: μ (effort 1) in float16 against μ as int8.
    bases = encoder.encode_arrays(names, x, m, tables)
    base_errors: dict[str, list[float]] = {"float16": [], "int8": []}
    sigma_log2_error = []
    for record, table in zip(bases, tables, strict=True):
        base_errors["float16"].append(relae(record, table))
        step, q = int8_with_step(record.mu)
        quantised = type(record)(record.name, np.float32(step) * q.astype(np.float32), record.sigma, record.meta)
        base_errors["int8"].append(relae(quantised, table))
        shared = sigma_from_codes(shared_sigma_code(record.sigma))
        sigma_log2_error.append(float(np.abs(np.log2(record.sigma / shared)).max()))
    rows: list[dict[str, Any]] = []
    for budget in BUDGETS:
        for label, allowed in (("encoder", True), ("latent-dtype base", False)):
            with replaced(rate, "compact_base_pays", lambda *args: False, active=not allowed):
                try:
                    records = BrdfEncoder(bytes=budget, latent_dtype="float16").encode_arrays(names, x, m, tables)
                except ValueError as error:  # the budget is below what this base needs
                    rows.append({"budget": budget, "policy": label, "refused": str(error)})
                    print(json.dumps(rows[-1]), flush=True)
                    continue
            layered = [r for r in records if isinstance(r, LayeredRecord)]
            row = {
                "budget": budget, "policy": label,
                "relae_mapped_mean": float(np.mean([relae(r, t) for r, t in zip(records, tables, strict=True)])),
                "payload_bytes_mean": float(np.mean([r.meta["rate"]["payload_bytes"] for r in records])),
                "basis_counts": sorted({r.basis.count for r in layered if r.basis is not None}),
                "compact_base": sorted({r.compact_mu for r in layered}),
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({
        "data": description, "materials": names, "effort": 1, "latent_dtype": "float16",
        "base_relae_mapped_mean": {k: float(np.mean(v)) for k, v in base_errors.items()},
        "shared_sigma_largest_log2_error": {"median": float(np.median(sigma_log2_error)),
                                            "max": float(np.max(sigma_log2_error))},
        "rows": rows, "seconds": time.perf_counter() - start,
    }, indent=1) + "\n")


if __name__ == "__main__":
    main()
