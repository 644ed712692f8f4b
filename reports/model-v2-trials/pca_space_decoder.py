"""Ablation (issue 12): an 8-D nonlinear decoder in PCA-coefficient space against the shipped conv decoder.

Usage::

    python reports/model-v2-trials/pca_space_decoder.py merl-nbrdf-proxy.h5 [-o pca_space_decoder.json]

On the dataset's training materials (76 NBRDF-proxy MERL materials), with
their 6 colour permutations (mapped colour blocks swapped): PCA to 96
components, then an MLP autoencoder 96 → 256 → 256 → 8 → 256 → 256 → 96
(SiLU) trained on L2 in table space (4,000 full-batch AdamW steps, lr 1e-3,
convex blends of random pairs added to each batch), with latent noise and
weight decay as listed. Held-out materials (14) are encoded, then the code
is refined for 200 Adam steps (lr 0.05) on the mapped L1 error of the kept
slices, as the codec refines. Printed and written: kept-slice mapped RelAE
(mean over materials) of PCA-k of the training materials (L2 projection),
the PCA-96 floor, each autoencoder (held-out at the encoder's code and
refined; training at the encoder's code), and the shipped v1 decoder
(held-out at μ and refined at effort 3). One seed; CPU, a few minutes each.
"""
import argparse
import itertools
import json
import time

import numpy as np
import torch

from brdfcodec.models.pca import fit_pca
from brdfcodec.codec import BrdfEncoder
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.codec.refine import refine_latent

COMPONENTS = 96
TRIALS = ((0.0, 0.0), (0.0, 0.1), (1e-2, 0.1), (0.0, 0.3))  # (weight decay, latent noise σ)


def relae(estimate: np.ndarray, x: np.ndarray) -> float:
    """Kept-slice mapped RelAE over the valid entries, mean over materials."""
    estimate = np.clip(estimate, 0, 5)
    return float((np.abs(estimate - x).sum(1) / np.abs(x).sum(1)).mean())


class AutoEncoder(torch.nn.Module):
    def __init__(self, hidden: int = 256, latent: int = 8) -> None:
        super().__init__()
        silu, linear = torch.nn.SiLU, torch.nn.Linear
        self.enc = torch.nn.Sequential(linear(COMPONENTS, hidden), silu(), linear(hidden, hidden), silu(),
                                       linear(hidden, latent))
        self.dec = torch.nn.Sequential(linear(latent, hidden), silu(), linear(hidden, hidden), silu(),
                                       linear(hidden, COMPONENTS))


def train(coefficients: np.ndarray, scale: np.ndarray, weight_decay: float, noise: float,
          steps: int = 4000) -> AutoEncoder:
    torch.manual_seed(0)
    net = AutoEncoder()
    c = torch.tensor(coefficients / scale, dtype=torch.float32)
    s = torch.tensor(scale, dtype=torch.float32)
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=weight_decay)
    for _ in range(steps):
        i = torch.randperm(len(c))
        a = torch.rand(len(c), 1)
        batch = torch.cat([c, a * c + (1 - a) * c[i]])  # the materials and convex blends of random pairs
        z = net.enc(batch)
        z = z + noise * torch.randn_like(z)
        loss = (((net.dec(z) - batch) * s) ** 2).sum(1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net


def evaluate(net: AutoEncoder, x: np.ndarray, mean: torch.Tensor, basis: torch.Tensor, scale: np.ndarray,
             steps: int = 200) -> float | tuple[float, float]:
    """RelAE at the encoder's code, and (steps > 0) after refining the code on the L1 error."""
    target = torch.tensor(x, dtype=torch.float32)
    s = torch.tensor(scale, dtype=torch.float32)
    with torch.no_grad():
        z = net.enc((target - mean) @ basis.T / s).clone()
    z.requires_grad_(True)
    opt = torch.optim.Adam([z], lr=0.05)
    at_code = 0.0
    for step in range(steps + 1):
        error = ((mean + (net.dec(z) * s) @ basis).clamp(0, 5) - target).abs().sum(1)
        value = float((error.detach() / target.abs().sum(1)).mean())
        if step == 0:
            at_code = value
        if step == steps:
            return at_code if steps == 0 else (at_code, value)
        opt.zero_grad()
        error.sum().backward()
        opt.step()
    raise AssertionError("unreachable")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("-o", "--output", default="reports/model-v2-trials/pca_space_decoder.json")
    args = parser.parse_args()
    torch.set_num_threads(2)
    with BrdfDataset(args.dataset) as d:
        train_rows, held_rows = d.indices("train"), d.indices("validation")
        xt, mt = d.inputs(train_rows), d.input_masks(train_rows)
        xv, mv = d.inputs(held_rows), d.input_masks(held_rows)
    entries = (mt.all(0) & mv.all(0)).reshape(-1)  # the same valid entries for every material here
    x_train = xt.reshape(len(xt), -1)[:, entries].astype(np.float64)
    x_held = xv.reshape(len(xv), -1)[:, entries].astype(np.float64)
    blocks = xt.reshape(len(xt), 3, 21, 90, 90)  # colour permutations: the mapped colour blocks swapped
    x_aug = np.concatenate([blocks[:, list(p)].reshape(len(xt), -1)[:, entries]
                            for p in itertools.permutations(range(3))]).astype(np.float64)
    results: dict[str, object] = {}
    pca_train = fit_pca(x_train, 75)
    mean0, basis0 = pca_train.mean, pca_train.components
    for k in (8, 16, 32, 64, 75):
        c = (x_held - mean0) @ basis0[:k].T
        results[f"pca-{k} (L2 projection)"] = relae(mean0 + c @ basis0[:k], x_held)
    print(results, flush=True)
    pca_aug = fit_pca(x_aug, COMPONENTS)
    mean_a, basis_a = pca_aug.mean, pca_aug.components
    results[f"pca-aug-{COMPONENTS} floor"] = relae(mean_a + ((x_held - mean_a) @ basis_a.T) @ basis_a, x_held)
    coefficients = (x_aug - mean_a) @ basis_a.T
    scale = coefficients.std(0) + 1e-9
    basis_t, mean_t = torch.tensor(basis_a, dtype=torch.float32), torch.tensor(mean_a, dtype=torch.float32)
    for weight_decay, noise in TRIALS:
        start = time.time()
        net = train(coefficients, scale, weight_decay, noise)
        held = evaluate(net, x_held, mean_t, basis_t, scale)
        trained = evaluate(net, x_train, mean_t, basis_t, scale, steps=0)
        results[f"mlp-ae wd={weight_decay} noise={noise}: held-out (enc, refined)"] = held
        results[f"mlp-ae wd={weight_decay} noise={noise}: train (enc)"] = trained
        print(weight_decay, noise, held, trained, round(time.time() - start), flush=True)
    encoder = BrdfEncoder(effort=0)
    decoder = encoder.decoder
    records = encoder.encode_arrays([f"m{i}" for i in range(len(xv))], xv, mv, [None] * len(xv))
    mu = np.stack([r.mu for r in records])
    refined = refine_latent(decoder.network, mu, xv, mv, 3)
    at_mu = decoder.decode_mapped(mu).reshape(len(xv), -1)[:, entries]
    at_refined = decoder.decode_mapped(refined).reshape(len(xv), -1)[:, entries]
    results["v1 conv decoder, held-out (mu, refined effort 3)"] = (relae(at_mu, x_held), relae(at_refined, x_held))
    print(json.dumps(results, indent=1))
    with open(args.output, "w") as f:
        json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
