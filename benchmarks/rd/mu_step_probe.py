"""What an entropy-coded latent could buy at 16 and 32 B (issue 48): μ on coarser grids, its ideal code length, and
the decode error it costs.

For the first 6 random analytic materials of ``runs/v3-held-out.h5`` (none trained on), each budget's library is
written as ``bvae bench rd`` writes it (the shipped model, effort 1, float16, ``--latent always``, the budget per
record). Each record's μ (stored on the int8 grid, step 1/32: D bytes) is then put on a grid of step t, its layers
kept as written (no refit: an upper bound on the cost), and the table decoded. The code length is the ideal one of
the integers under the latent prior N(0, 1) discretised at step t, plus one byte for a step code: what an
arithmetic-coded μ would take, against the D bytes of the int8 grid. Budgets a few bytes above 16 and 32, written
as they are, say what the bytes saved would buy in layers.

usage: python benchmarks/rd/mu_step_probe.py [-o reports/results/mu-step-probe.jsonl]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

import brdfcodec as bc
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.layers.entropy_coding import MAX_BOUND, ideal_code_length_bits
from brdfcodec.report.rows import stamp, write_rows
from brdfcodec.representation.metrics import relae_mapped

MODEL = "brdfcodec/data/models/default"
DATASET = "runs/v3-held-out.h5"
#: The budgets whose μ is moved to coarser grids, and those written only as they are (what 2 to 8 more bytes of
#: layers buy at the same μ: the other side of the trade).
BUDGETS = (16, 32)
LADDER = (18, 20, 24, 34, 36)
STEPS = (1 / 32, 1 / 16, 1 / 8, 1 / 4)


def ideal_bytes(q: np.ndarray, step: float) -> float:
    """Bytes of the integers ``q`` under N(0, 1) discretised at ``step`` (ideal code length), plus a step byte."""
    spreads = np.full(len(q), 1.0 / step)  # the prior's σ in steps
    return (ideal_code_length_bits(q.astype(np.int64), spreads, bound=MAX_BOUND, prior="gaussian") + 8) / 8


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="reports/results/mu-step-probe.jsonl")
    args = parser.parse_args()
    with BrdfDataset(DATASET) as dataset:
        rows = dataset.indices(family="analytic")[:6]
        items = [bc.MaterialInput(dataset.names[i], dataset.inputs([i])[0], dataset.table(i),
                                  dataset.input_masks([i])[0]) for i in rows]
    decoder = bc.BrdfDecoder(MODEL)
    out = []
    for budget in sorted(BUDGETS + LADDER):
        data = bc.encode(items, model=MODEL, latent_dtype="float16", measure_error=False, effort=1, bytes=budget,
                         latent="always")
        library = bc.decode(data, decoder=decoder)
        for step in STEPS if budget in BUDGETS else STEPS[:1]:
            errors, sizes = [], []
            for item in items:
                record = library.record(item.name)
                q = np.rint(np.asarray(record.mu, np.float64) / step)
                moved = dataclasses.replace(record, mu=(q * step).astype(np.float32), compact_mu=False,
                                            fixed_mu_grid=False, stored_mu=None)
                table = np.asarray(decoder.decode(moved, masked="unmeasured"), np.float64)
                errors.append(relae_mapped(item.source.values, table, item.source.mask).overall)
                sizes.append(ideal_bytes(q, step))
            out.append({"budget_bytes": budget, "mu_step": step, "materials": len(items),
                        "mapped_relae_mean": float(np.mean(errors)), "per_material_mapped": errors,
                        "mu_bytes_ideal_mean": float(np.mean(sizes)), "mu_bytes_int8_grid": decoder.latent_dim})
            print(f"{budget} B, μ step 1/{round(1 / step)}: mapped RelAE {np.mean(errors):.4f}, "
                  f"μ {np.mean(sizes):.2f} B coded (int8 grid: {decoder.latent_dim} B)", flush=True)
    command = "python benchmarks/rd/mu_step_probe.py" + ("" if args.output == parser.get_default("output")
                                                          else f" -o {args.output}")
    write_rows(args.output, stamp(out, study="mu-step-probe", command=command, dataset=DATASET, model=MODEL))


if __name__ == "__main__":
    main()
