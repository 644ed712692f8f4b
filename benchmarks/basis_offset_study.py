"""Which basis vectors a record's coefficients should weigh: from the first, or after the decoder's own (issue 14).

Usage::

    python benchmarks/basis_offset_study.py DATASET.h5 [-o reports/rd-study/basis-offset.json]

The shipped decoder has a linear path over the first ``latent_dim``
principal components of its training materials, and its shared basis'
leading vectors are the same components. On the dataset's held-out
(validation) materials this measures the kept-slice mapped RelAE (valid
entries, clamped) of the encoder's layered base at effort 1 — μ and k
coefficients fitted jointly (:func:`brdfcodec.codec.refine.fit_basis_coefficients`),
the coefficients quantised to int8 as in a file, μ rounded to float16 —
with the coefficients on vectors ``0 … k−1`` and on ``8 … 8+k−1``
(``first`` = 8, format 1.3). PCA-k of the training split with the same
int8 quantisation is listed beside it.
"""

from __future__ import annotations

import json
import time

import numpy as np
from basis_study import (  # sibling script: Python puts the running script's folder on sys.path
    kept_slice_relae,
    study_arguments,
)

from brdfcodec.codec import BrdfEncoder
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.layers.basis import quantise_coefficients
from brdfcodec.codec.refine import fit_basis_coefficients

COUNTS = (6, 14, 22, 30, 38, 54)
OFFSETS = (0, 8)


def main() -> None:
    args = study_arguments(__doc__, "reports/rd-study/basis-offset.json")
    start = time.perf_counter()
    with BrdfDataset(args.dataset) as dataset:
        held, train = dataset.indices("validation"), dataset.indices("train")
        x, m, x_train = dataset.inputs(held), dataset.input_masks(held), dataset.inputs(train)
        description = dataset.description
    encoder = BrdfEncoder(effort=1)
    decoder = encoder.decoder
    basis = decoder.shared_basis
    if basis is None:
        raise SystemExit("the default model has no shared basis")
    records = encoder.encode_arrays([f"m{i}" for i in range(len(x))], x, m, [None] * len(x))
    mu = np.stack([r.mu for r in records])
    rows: list[dict[str, float | int]] = [
        {"k": 0, "base": kept_slice_relae(decoder.decode_mapped(mu.astype(np.float16).astype(np.float32)), x, m)}
    ]
    entries = basis.entries
    train_flat = x_train.reshape(len(x_train), -1)[:, entries].astype(np.float64)
    mean = train_flat.mean(axis=0)
    pca = np.linalg.svd(train_flat - mean, full_matrices=False)[2]
    held_flat = x.reshape(len(x), -1)[:, entries].astype(np.float64)
    for k in COUNTS:
        row: dict[str, float | int] = {"k": k}
        estimate = np.zeros((len(x), x[0].size))
        for i, c in enumerate((held_flat - mean) @ pca[:k].T):
            estimate[i, entries] = mean + quantise_coefficients(basis.sha256, c).coefficients() @ pca[:k]
        row["pca-int8"] = kept_slice_relae(estimate.reshape(x.shape), x, m)
        for first in OFFSETS:
            components = basis.vectors(first, k)
            decoded = []
            for i in range(len(x)):
                z, c = fit_basis_coefficients(decoder.network, mu[i : i + 1], x[i : i + 1], m[i : i + 1], components,
                                              entries, 1)
                layer = quantise_coefficients(basis.sha256, c[0], first)
                code = z.astype(np.float16).astype(np.float32)
                decoded.append(decoder.decode_mapped(code)[0] + basis.residual(layer.coefficients(), first))
            row[f"first={first}"] = kept_slice_relae(np.stack(decoded), x, m)
        print(row, flush=True)
        rows.append(row)
    result = {"dataset": description, "held_out": len(held), "train": len(train),
              "metric": "kept-slice mapped RelAE, held-out mean (μ float16, coefficients int8, effort 1)",
              "command": f"python benchmarks/basis_offset_study.py {args.dataset}",
              "seconds": time.perf_counter() - start, "rows": rows}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
