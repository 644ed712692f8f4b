"""Rate–distortion study on a dataset file: what each enhancement layer could gain (issue 14).

Measures, on the kept slices in the mapped domain (valid entries only, the
network's view; the full-table RelAE adds the slice-interpolation floor):

1. encode-time refinement of the latent: kept-slice mapped RelAE per number of
   optimiser steps, training and held-out materials, and the time per step;
2. a residual basis fitted on the training materials' residuals: held-out
   error against the number of components k, coefficients as float16 and as
   integers at a few quantisation steps (zstandard-packed bytes);
3. a per-material detail layer: the residual left after the basis, uniformly
   quantised at a step Δ and packed with zstandard: bytes against error;
4. the same-bytes baselines: PCA-k of the inputs, and zstandard over the
   quantised kept slices themselves.

Usage::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/rd_study.py /work/data/merl-nbrdf-proxy.h5 -o rd-study.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch
import zstandard

from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.datasets.hdf5 import BrdfDataset


def relae(estimate: np.ndarray, target: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-material kept-slice mapped RelAE."""
    axes = tuple(range(1, target.ndim))
    return (np.abs(estimate - target) * mask).sum(axis=axes) / (np.abs(target) * mask).sum(axis=axes)


def refine(decoder: BrdfDecoder, mu: np.ndarray, x: np.ndarray, m: np.ndarray, steps: int, lr: float, loss: str):
    z = torch.tensor(mu, requires_grad=True)
    target, mask = torch.from_numpy(x), torch.from_numpy(m.astype(np.float32))
    optimiser = torch.optim.Adam([z], lr=lr)
    history = []
    best = z.detach().clone()
    best_loss = np.full(len(mu), np.inf)
    for _ in range(steps + 1):
        out = decoder.network(z)
        diff = (out - target) * mask
        per = (diff.abs() if loss == "l1" else diff.square()).flatten(1).sum(1)
        err = (diff.abs().flatten(1).sum(1) / (target * mask).flatten(1).sum(1)).detach().numpy()
        better = err < best_loss
        best[better] = z.detach()[better]
        best_loss = np.minimum(best_loss, err)
        history.append(best_loss.copy())
        optimiser.zero_grad()
        per.sum().backward()
        optimiser.step()
    return best.numpy(), history


def pack(q: np.ndarray, level: int = 19) -> int:
    return len(zstandard.ZstdCompressor(level=level).compress(q.tobytes()))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("dataset")
    parser.add_argument("-o", "--output", default="rd-study.json")
    parser.add_argument("--steps", type=int, default=40)
    args = parser.parse_args()
    torch.set_num_threads(1)
    results: dict = {}
    with BrdfDataset(args.dataset) as ds:
        train, held = ds.indices("train"), ds.indices("validation")
        x = ds.inputs().astype(np.float32)
        m = ds.input_masks()
    encoder, decoder = BrdfEncoder(), BrdfDecoder()
    mu, _ = encoder.posterior_from_inputs(x)
    for p in decoder.network.parameters():
        p.requires_grad_(False)

    # 1. refinement
    for loss, lr in (("l1", 0.05), ("l2", 0.05)):
        for name, idx in (("train", train[:20]), ("held-out", held)):
            t0 = time.perf_counter()
            _, history = refine(decoder, mu[idx], x[idx], m[idx], args.steps, lr, loss)
            per_step = (time.perf_counter() - t0) / (args.steps + 1) / len(idx)
            curve = {s: float(history[s].mean()) for s in (0, 2, 5, 10, 20, args.steps)}
            results[f"refine-{loss}-{name}"] = {"relae_by_steps": curve, "seconds_per_step_per_material": per_step}
            print(loss, name, curve, f"{per_step * 1e3:.0f} ms/step/material", flush=True)

    # refined latents at 20 steps of L1 for everything (the basis is fitted on refined residuals)
    z_all = np.empty_like(mu)
    for start in range(0, len(mu), 15):
        sl = slice(start, start + 15)
        z_all[sl], _ = refine(decoder, mu[sl], x[sl], m[sl], 20, 0.05, "l1")
    with torch.inference_mode():
        base = np.concatenate([decoder.network(torch.from_numpy(z_all[i : i + 15])).numpy() for i in range(0, 90, 15)])
    residual = (x - base) * m
    print("base refined-20 held-out", relae(base, x, m)[held].mean(), "train", relae(base, x, m)[train].mean())

    # 2. residual basis (SVD of training residuals; Gram trick)
    flat_train = residual[train].reshape(len(train), -1).astype(np.float64)
    gram = flat_train @ flat_train.T
    evals, evecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1]
    evals, evecs = evals[order], evecs[:, order]
    keep = evals > evals[0] * 1e-10
    comps = (evecs[:, keep].T @ flat_train) / np.sqrt(evals[keep])[:, None]
    comps = comps.astype(np.float32)
    flat_held = residual[held].reshape(len(held), -1)
    coeffs = flat_held @ comps.T
    basis_curve = {}
    for k in (4, 8, 16, 24, 32, 48, 64, 75):
        if k > len(comps):
            continue
        c16 = coeffs[:, :k].astype(np.float16).astype(np.float32)
        rec = base[held] + (c16 @ comps[:k]).reshape(len(held), *x.shape[1:])
        err = relae(np.clip(rec, 0, 5), x[held], m[held]).mean()
        row = {"float16": float(err)}
        for step in (0.02, 0.05, 0.1):
            q = np.round(coeffs[:, :k] / step)
            recq = base[held] + ((q * step).astype(np.float32) @ comps[:k]).reshape(len(held), *x.shape[1:])
            row[f"q{step}"] = float(relae(np.clip(recq, 0, 5), x[held], m[held]).mean())
            row[f"q{step}-bytes"] = float(np.mean([pack(qi.astype(np.int16), 19) for qi in q]))
        basis_curve[k] = row
        print("basis k", k, row, flush=True)
    results["residual-basis"] = basis_curve
    results["coeff-std-held"] = coeffs.std(0)[:32].tolist()

    # 3. detail layer on top of base + basis-k
    detail = {}
    for k in (0, 32):
        rec = base[held] + ((coeffs[:, :k] @ comps[:k]).reshape(len(held), *x.shape[1:]) if k else 0)
        left = (x[held] - rec) * m[held]
        for step in (0.004, 0.008, 0.016, 0.032, 0.064):
            q = np.round(left / step).astype(np.int16)
            err = relae(np.clip(rec + q * step, 0, 5), x[held], m[held]).mean()
            # pack only valid entries (mask is known to the decoder)
            nbytes = np.mean([pack(q[i][m[held][i]].astype(np.int8 if np.abs(q[i]).max() < 128 else np.int16), 19)
                              for i in range(len(held))])
            detail[f"k{k}-step{step}"] = {"relae": float(err), "bytes": float(nbytes)}
            print("detail", k, step, err, nbytes, flush=True)
    results["detail"] = detail

    # 4. baseline: zstd over quantised kept slices themselves
    zs = {}
    for step in (0.004, 0.008, 0.016, 0.032):
        q = np.round(x[held] / step).astype(np.int16)
        err = relae(q * step, x[held], m[held]).mean()
        nbytes = np.mean([pack(q[i][m[held][i]], 19) for i in range(len(held))])
        zs[step] = {"relae": float(err), "bytes": float(nbytes)}
        print("zstd-quant", step, err, nbytes, flush=True)
    results["zstd-quantised-slices"] = zs
    with open(args.output, "w") as f:
        json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
