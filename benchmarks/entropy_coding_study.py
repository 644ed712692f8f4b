"""Would entropy-coded coefficients let the basis layer beat PCA at 16–64 B? (issue 14).

Usage::

    python benchmarks/entropy_coding_study.py DATASET.h5 [-o reports/rd-study/entropy-coding.json]

The report's basis layer and its PCA baselines store coefficients as int8
with one float16 step (max |c| / 127). A coefficient far down the spectrum
then still costs a whole byte though it rounds to a few levels. This study
measures what a variable-length code would buy each side, packed the same
way, on the dataset's held-out (validation) materials:

- ``bvae-int8``: today's small records: compact base (μ as int8 with a
  float16 step, one shared σ byte: 11 bytes for D = 8), then k coefficients
  on the shared basis from vector 8 on (as the encoder places them), a
  float16 step and k int8 values. μ and the coefficients are fitted together
  at effort 1, μ rounded to its int8 code and the coefficients refitted to
  it, as :mod:`brdfcodec.codec.encoding` does;
- ``bvae-exp-golomb``: the same base and fit, the coefficients quantised with
  a uniform step s from :data:`STEPS` and stored as signed Exp-Golomb codes
  (zig-zag, order 0–3 chosen per record: 2 bits) after a float16 step;
- ``pca-int8`` / ``pca-exp-golomb``: PCA-k of the training split
  (least-squares coefficients, as the report's baseline), packed the same two
  ways (the step is its only overhead).

For every material and size, each side takes its best (k, s) whose payload
fits (judged on the kept slices, as the encoder's rate control does); the
rows give the mean full-table mapped RelAE of those choices and their mean
payload. Bytes are counted, not written: this measures the packing, not a
format (``spec/bvae-format.md`` has no Exp-Golomb layer).
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np

# sibling script: Python puts the running script's folder on sys.path
from basis_study import kept_slice_relae, study_arguments

from brdfcodec.models.pca import fit_pca
from brdfcodec.codec import BrdfEncoder
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.layers.basis import basis_offset, dequantise_int8, int8_with_step
from brdfcodec.codec.refine import fit_basis_coefficients, refine_latent
from brdfcodec.representation.metrics import error_report
from brdfcodec.representation.network_io import table_from_network_output

#: Coefficient counts tried (0: the base alone, for the bvae side).
COUNTS = (0, 2, 3, 4, 5, 6, 8, 10, 12, 14, 16, 19, 22, 26, 30, 36, 42, 48, 56, 64, 75)
#: Uniform quantisation steps tried for the Exp-Golomb codes (mapped units).
STEPS = tuple(2.0 ** (e / 2) for e in range(-6, 9))
BUDGETS = (16, 24, 32, 48, 64, 96, 128)
#: Compact base (float16 μ step, D int8 values, one shared σ byte) and a float16 coefficient step.
BASE_BYTES, STEP_BYTES = 11, 2


def exp_golomb_bits(q: np.ndarray) -> int:
    """Bits of signed integers as zig-zag Exp-Golomb codes of the best order r in 0…3, plus 2 bits for r."""
    u = np.where(q >= 0, 2 * q, -2 * q - 1).astype(np.float64)
    return min(int((2 * np.floor(np.log2(u / 2**r + 1)) + 1 + r).sum()) for r in range(4)) + 2


def main() -> None:
    args = study_arguments(__doc__, "reports/rd-study/entropy-coding.json")
    start = time.perf_counter()
    with BrdfDataset(args.dataset) as dataset:
        train, held = dataset.indices("train"), dataset.indices("validation")
        pca = fit_pca(dataset.inputs(train), min(75, len(train) - 1))
        x, m = dataset.inputs(held), dataset.input_masks(held)
        tables, names, description = [dataset.table(i) for i in held], [dataset.names[i] for i in held], \
            dataset.description
    encoder = BrdfEncoder(effort=0)
    decoder, basis = encoder.decoder, encoder.decoder.shared_basis
    if basis is None:
        raise SystemExit("the default model has no shared basis")
    n = len(x)
    mu = np.stack([r.mu for r in encoder.encode_arrays(names, x, m, [None] * n)])
    refined = refine_latent(decoder.network, mu, x, m, 1)
    linear_rank = decoder.network.config.latent_dim if decoder.network.config.linear_basis else 0

    # candidates[side][i]: (payload bytes, kept-slice RelAE, how to rebuild the mapped slices)
    candidates: dict[str, list[list[tuple[int, float, tuple[Any, ...]]]]] = {
        side: [[] for _ in range(n)] for side in ("bvae-int8", "bvae-exp-golomb", "pca-int8", "pca-exp-golomb")}
    fits: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, int]] = {}

    def error(estimate: np.ndarray, i: int) -> float:
        return kept_slice_relae(estimate[None], x[i : i + 1], m[i : i + 1])

    def rebuild(key: tuple[Any, ...], i: int) -> np.ndarray:
        side, k, step = key
        if side == "bvae":
            _, coefficients, base, first = fits[k]
            q = np.rint(coefficients[i] / step)
            return base[i] + (basis.residual(q * step, first) if k else 0.0)
        c = (x[i].reshape(-1) - pca.mean) @ pca.components[:k].T
        return (pca.mean + np.rint(c / step) * step @ pca.components[:k]).reshape(x[i].shape)

    for k in [c for c in COUNTS if c <= min(basis.count, pca.n_components)]:
        first = basis_offset(linear_rank, basis.count, k)
        if k:
            codes, _ = fit_basis_coefficients(decoder.network, refined, x, m, basis.vectors(first, k),
                                              basis.entries, 1)
        else:
            codes = refined
        compact = np.stack([dequantise_int8(*int8_with_step(z)) for z in codes])
        coefficients = (fit_basis_coefficients(decoder.network, compact, x, m, basis.vectors(first, k),
                                               basis.entries, 1, fit_latent=False)[1] if k else np.zeros((n, 0)))
        fits[k] = (compact, coefficients, decoder.decode_mapped(compact), first)
        for i in range(n):
            pca_c = (x[i].reshape(-1) - pca.mean) @ pca.components[:k].T
            for side, c, overhead in (("bvae", coefficients[i], BASE_BYTES), ("pca", pca_c, 0)):
                if k == 0:
                    if side == "bvae":
                        base_alone = (BASE_BYTES, error(fits[0][2][i], i), ("bvae", 0, 1.0))
                        for packing in ("int8", "exp-golomb"):
                            candidates[f"bvae-{packing}"][i].append(base_alone)
                    continue
                step, _ = int8_with_step(c)
                key = (side, k, step)
                candidates[f"{side}-int8"][i].append((overhead + STEP_BYTES + k, error(rebuild(key, i), i), key))
                for step in STEPS:
                    key = (side, k, step)
                    size = overhead + STEP_BYTES + (exp_golomb_bits(np.rint(c / step)) + 7) // 8
                    candidates[f"{side}-exp-golomb"][i].append((size, error(rebuild(key, i), i), key))
        print(json.dumps({"k": k, "seconds": round(time.perf_counter() - start)}), flush=True)

    rows = []
    for budget in BUDGETS:
        row: dict[str, Any] = {"budget": budget}
        for side, per_material in candidates.items():
            chosen = [min((c for c in options if c[0] <= budget), key=lambda c: c[1], default=None)
                      for options in per_material]
            if any(c is None for c in chosen):
                continue
            errors = [error_report(tables[i].values, table_from_network_output(rebuild(c[2], i)).astype(np.float64),
                                   tables[i].mask).relae_mapped.overall for i, c in enumerate(chosen)]
            row[side] = {"relae_mapped_mean": float(np.mean(errors)),
                         "payload_bytes_mean": float(np.mean([c[0] for c in chosen])),
                         "coefficients_median": float(np.median([c[2][1] for c in chosen]))}
        rows.append(row)
        print(json.dumps(row), flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({
        "data": description, "materials": names, "train": len(train), "effort": 1,
        "metric": "full-table mapped RelAE, held-out mean; (k, step) chosen per material on the kept slices",
        "command": f"python benchmarks/entropy_coding_study.py {args.dataset}",
        "rows": rows, "seconds": time.perf_counter() - start,
    }, indent=1) + "\n")


if __name__ == "__main__":
    main()
