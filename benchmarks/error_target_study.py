"""What a compact base saves under an error target (issue 14: ``--max-relae`` on small records).

Usage::

    python benchmarks/error_target_study.py DATASET.h5 [-o reports/rd-study/error-target.json]

Encodes the dataset's held-out (validation) materials with the default model
at several error targets (``BrdfEncoder(max_relae=X)``, effort 1, float16
latents, mapped RelAE), once with the encoder's sequence
(:func:`~brdfcodec.codec.rate.error_target_sequence`: basis-only records on
a compact base) and once with the sequence before it (the base alone, then
4, 8, 16 and K coefficients, all on the base in the latent dtype), and
records per target and policy the mean payload, how many materials met the
target and the worst RelAE reached (full table, measured on the returned record).
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np

# sibling script: Python puts the running script's folder on sys.path
from basis_study import held_out_materials, replaced, study_arguments

import brdfcodec.codec.rate as rate
from brdfcodec.codec import BrdfEncoder, measure

TARGETS = (0.06, 0.05, 0.04, 0.03, 0.02)


def sequence_before(basis_count: int) -> list[tuple[bool, int, float | None]]:
    """The error-target sequence before compact bases: the base alone, then 4, 8, 16 and K coefficients, then K
    under each rung, all on the base in the latent dtype."""
    counts = [n for n in (4, 8, 16) if n < basis_count] + [basis_count]
    return [(False, 0, None), *((False, n, None) for n in counts),
            *((False, basis_count, s) for s in rate.STEP_LADDER)]


def main() -> None:
    args = study_arguments(__doc__, "reports/rd-study/error-target.json")
    start = time.perf_counter()
    held = held_out_materials(args.dataset)
    rows: list[dict[str, Any]] = []
    for target in TARGETS:
        for label, old in (("encoder", False), ("latent-dtype base", True)):
            with replaced(rate, "error_target_sequence", sequence_before, active=old):
                encoder = BrdfEncoder(max_relae=target, latent_dtype="float16")
                records = encoder.encode_arrays(held.names, held.inputs, held.masks, held.tables)
            reached = [measure(r, encoder.decoder, t).meta["relae"]["mapped"]
                       for r, t in zip(records, held.tables, strict=True)]
            row = {
                "max_relae": target, "policy": label,
                "payload_bytes_mean": float(np.mean([r.meta["rate"]["payload_bytes"] for r in records])),
                "payload_bytes": [r.meta["rate"]["payload_bytes"] for r in records],
                "met": int(sum(x <= target for x in reached)), "materials": len(records),
                "relae_mapped_worst": float(max(reached)),
            }
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if k != "payload_bytes"}), flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({
        "data": held.description, "materials": held.names, "effort": 1, "latent_dtype": "float16",
        "metric": "mapped", "rows": rows, "seconds": time.perf_counter() - start,
    }, indent=1) + "\n")


if __name__ == "__main__":
    main()
