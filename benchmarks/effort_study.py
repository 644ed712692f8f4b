"""Refinement effort levels 0–3 on the proxy dataset: full-table mapped RelAE and encode time (issue 14).

Held-out materials (all of them) and as many training materials, base records
only (no detail layer), float32 latents, one material at a time.

Usage::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/effort_study.py DATASET.h5 -o effort.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from brdfcodec.codec import BrdfEncoder, measure
from brdfcodec.datasets.hdf5 import BrdfDataset


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("dataset")
    parser.add_argument("-o", "--output", default="effort.json")
    args = parser.parse_args()
    results = {}
    with BrdfDataset(args.dataset) as ds:
        held = ds.indices("validation")
        train = ds.indices("train")[: len(held)]
        tables = {i: ds.table(i) for i in held + train}
    encoders = {effort: BrdfEncoder(effort=effort) for effort in range(4)}
    for effort, encoder in encoders.items():
        for split, indices in (("held-out", held), ("train", train)):
            errors, times = [], []
            for i in indices:
                start = time.perf_counter()
                record = encoder.encode(tables[i])
                times.append(time.perf_counter() - start)
                errors.append(measure(record, encoder.decoder, tables[i]).meta["relae"]["mapped"])
            results[f"effort{effort}-{split}"] = {"relae_mapped_mean": float(np.mean(errors)),
                                                  "encode_s_median": float(np.median(times))}
            print(effort, split, results[f"effort{effort}-{split}"], flush=True)
    with open(args.output, "w") as f:
        json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
