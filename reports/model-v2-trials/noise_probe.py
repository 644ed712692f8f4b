"""How much the posterior noise matters: decode μ + s·ε and measure the reconstruction error.

Encodes training and validation materials of a dataset with a model folder's
encoder, prints the median posterior σ and the spread of μ, then decodes
``μ + s·ε`` (ε ~ N(0, I), four draws) for a few noise scales ``s`` and prints
the summed L1 error over valid mapped entries (the training objective's term)
and that error per valid entry. If the error barely moves at ``s`` equal to the
posterior σ, the KL term of the objective is not shaping the latent.

Usage::

    python reports/model-v2-trials/noise_probe.py MODEL_FOLDER DATASET.h5
"""

from __future__ import annotations

import argparse

import torch

from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.models.store import load_model

NOISE_SCALES = (0.0, 0.01, 0.03, 0.1, 0.3, 1.0)
TRAIN_ROWS = 12  # enough for a mean; all validation rows are used
DRAWS = 4


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="model folder (bvae model export)")
    parser.add_argument("dataset", help="dataset file (bvae dataset build)")
    args = parser.parse_args()
    torch.set_num_threads(2)
    encoder, decoder, _ = load_model(args.model, parts=("encoder", "decoder"), device="cpu")
    encoder.eval()
    decoder.eval()
    generator = torch.Generator().manual_seed(0)
    with BrdfDataset(args.dataset) as dataset, torch.no_grad():
        for split in ("train", "validation"):
            rows = dataset.indices(split)
            rows = rows[:TRAIN_ROWS] if split == "train" else rows
            x = torch.as_tensor(dataset.inputs(rows))
            mask = torch.as_tensor(dataset.input_masks(rows)).float()
            mu, logvar = encoder(x)
            sigma = torch.exp(0.5 * logvar)
            print(f"{split} ({len(rows)} materials): posterior σ median {float(sigma.median()):.4f}, "
                  f"μ std {float(mu.std()):.3f}")
            valid = mask.flatten(1).sum(1)
            for scale in NOISE_SCALES:
                errors = []
                for _ in range(DRAWS):
                    z = mu + scale * torch.randn(mu.shape, generator=generator)
                    errors.append(((decoder(z) - x).abs() * mask).flatten(1).sum(1))
                error = torch.stack(errors).mean(0)
                print(f"  s = {scale:<5g} summed L1 {float(error.mean()):8.0f}   "
                      f"per valid entry {float((error / valid).mean()):.4f}")


if __name__ == "__main__":
    main()
