"""What harder refinement buys a small size budget (issue 14).

Usage::

    python benchmarks/budget_effort_study.py DATASET.h5 [-o reports/rd-study/budget-effort.json]
        [--budgets 16,32,64] [--efforts 1,2,3]

Encodes the dataset's held-out (validation) materials as the report's
``bvae-layered@N`` points do (``BrdfEncoder(bytes=N)``, float16 latents) at
16 B, 32 B and 64 B, with refinement effort 1 (the default), 2 and 3, and
records the mean full-table mapped RelAE, payload and encode time of each.

Other budgets answer other questions: ``--budgets 32,35,64,67 --efforts 1``
(``reports/rd-study/base-overhead.json``) measures what the 3 bytes of a
compact base's own overhead (μ's float16 step and the shared σ byte) would
buy if a record dropped them: the 32 B and 64 B points with 3 more bytes of
coefficients.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

# sibling script: Python puts the running script's folder on sys.path
from basis_study import held_out_materials, study_arguments

from brdfcodec.codec import BrdfEncoder
from brdfcodec.representation.metrics import error_report

BUDGETS = (16, 32, 64)
EFFORTS = (1, 2, 3)


def _integers(text: str) -> tuple[int, ...]:
    """A comma-separated list of integers, as ``--budgets`` and ``--efforts`` take them."""
    try:
        return tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def _options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--budgets", type=_integers, default=BUDGETS, help="payload budgets in bytes (16,32,64)")
    parser.add_argument("--efforts", type=_integers, default=EFFORTS, help="refinement efforts (1,2,3)")


def main() -> None:
    args = study_arguments(__doc__, "reports/rd-study/budget-effort.json", _options)
    start = time.perf_counter()
    held = held_out_materials(args.dataset)
    rows = []
    for effort in args.efforts:
        for budget in args.budgets:
            encoder = BrdfEncoder(bytes=budget, latent_dtype="float16", effort=effort)
            began = time.perf_counter()
            records = encoder.encode_arrays(held.names, held.inputs, held.masks, held.tables)
            seconds = time.perf_counter() - began
            errors = [error_report(table.values, encoder.decoder.decode(record, masked="keep").astype(np.float64),
                                   table.mask).relae_mapped.overall for record, table in zip(records, held.tables,
                                                                                            strict=True)]
            rows.append({"effort": effort, "budget": budget, "relae_mapped_mean": float(np.mean(errors)),
                         "payload_bytes_mean": float(np.mean([r.meta["rate"]["payload_bytes"] for r in records])),
                         "encode_seconds_per_material": seconds / len(records)})
            print(json.dumps(rows[-1]), flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({
        "data": held.description, "materials": held.names, "latent_dtype": "float16",
        "metric": "full-table mapped RelAE, held-out mean",
        "command": " ".join(["python benchmarks/budget_effort_study.py", str(args.dataset),
                             "--budgets", ",".join(map(str, args.budgets)),
                             "--efforts", ",".join(map(str, args.efforts))]),
        "rows": rows, "seconds": time.perf_counter() - start,
    }, indent=1) + "\n")


if __name__ == "__main__":
    main()
