"""Which never-seen analytic materials the supervised models of the saturation study decode worse than the shipped
model, and what those materials are (issue 50): the mapped RelAE of the encoder's μ decoded (effort 0), per
material, beside its kind (metal or dielectric), colour (saturation and hue of the diffuse colour, or of F0 for a
metal) and GGX roughness α.

usage (repository root, after the saturation study's exports; runs/ as from_scratch_rows.py describes):

    python reports/disentanglement/never_seen_per_material.py [-o reports/disentanglement/saturation-per-material.jsonl]
"""

from __future__ import annotations

import argparse
import colorsys

import numpy as np

import brdfcodec as bc
from brdfcodec.datasets.analytic import random_analytic_materials
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.report.rows import stamp, write_rows
from brdfcodec.representation.metrics import relae_mapped

DATASET = "runs/v3-held-out.h5"
MODELS = {"bvae-nbrdf-proxy-small-v3": "brdfcodec/data/models/default",
          "bvae-scratch-sat-w10k": "runs/models/dev3-sat-w10k",
          "bvae-scratch-sat-w5k": "runs/models/dev3-sat-w5k"}
#: Materials sharper than this (GGX α) are counted apart: the factor family draws α from 0.03 (``factor_material``).
SHARP_ALPHA = 0.06


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="reports/disentanglement/saturation-per-material.jsonl")
    args = parser.parse_args()
    with BrdfDataset(DATASET) as dataset:
        rows = [i for i, family in enumerate(dataset.families) if family == "analytic"]
        names = [dataset.names[i] for i in rows]
        inputs = dataset.inputs(rows)
        references = [dataset.table(i) for i in rows]
    materials = {m.name: m for m in random_analytic_materials(len(names), seed=0)}
    errors: dict[str, list[float]] = {}
    for label, folder in MODELS.items():
        encoder, decoder = bc.BrdfEncoder(folder, effort=0), bc.BrdfDecoder(folder)
        mu, _ = encoder.posterior_from_inputs(inputs)
        errors[label] = [
            relae_mapped(reference.values, np.asarray(decoder.decode(LatentRecord(name, code.astype(np.float32),
                                                                                  np.ones_like(code, np.float32))),
                                                      np.float64), reference.mask).overall
            for name, code, reference in zip(names, mu, references, strict=True)]
    out = []
    for index, name in enumerate(names):
        material = materials[name]
        metal = max(material.diffuse) == 0
        colour = np.asarray(material.specular if metal else material.diffuse, dtype=float)
        hue, saturation, _ = colorsys.rgb_to_hsv(*(colour / max(colour.max(), 1e-12)))
        out.append({"material": name, "kind": "metal" if metal else "dielectric", "colour": colour.tolist(),
                    "saturation": saturation, "hue": hue, "alpha": material.roughness,
                    "mapped_relae": {label: values[index] for label, values in errors.items()}})
    sharp = [row["alpha"] < SHARP_ALPHA for row in out]
    for label in MODELS:
        values = np.array([row["mapped_relae"][label] for row in out])
        print(f"{label}: all {values.mean():.4f}; α < {SHARP_ALPHA}: {values[sharp].mean():.4f} "
              f"({sum(sharp)}); α ≥ {SHARP_ALPHA}: {values[~np.array(sharp)].mean():.4f} ({len(out) - sum(sharp)})")
    write_rows(args.output, stamp(out, study="saturation-per-material", dataset=DATASET, models=MODELS,
                                  command="python reports/disentanglement/never_seen_per_material.py"))


if __name__ == "__main__":
    main()
