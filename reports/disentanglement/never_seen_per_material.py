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
from from_scratch_rows import SATURATION

import brdfcodec as bc
from brdfcodec.datasets.analytic import random_analytic_materials
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.report.rows import stamp, write_rows
from brdfcodec.training.evaluation import MappedReference

DATASET = "runs/v3-held-out.h5"
#: The shipped model and the study's two runs at one analytic material a step (its fb4 run left out).
MODELS = {label: folder for label, folder in SATURATION.models.items() if not label.endswith("-fb4")}
#: Materials sharper than this (GGX α) are counted apart: the factor family draws α from 0.03 (``factor_material``).
SHARP_ALPHA = 0.06


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="reports/disentanglement/saturation-per-material.jsonl")
    args = parser.parse_args()
    with BrdfDataset(DATASET) as dataset:
        rows = dataset.indices(family="analytic")
        names = [dataset.names[i] for i in rows]
        inputs = dataset.inputs(rows)
        reference = MappedReference(dataset, rows)
        # the dataset's random materials, rebuilt from the seed it was built with (`bvae dataset build --seed`)
        seed = int(dataset.attribute("split_seed"))
        materials = {m.name: m for m in random_analytic_materials(len(names), seed=seed)}
    errors: dict[str, list[float]] = {}
    for label, folder in MODELS.items():
        encoder, decoder = bc.BrdfEncoder(folder, effort=0), bc.BrdfDecoder(folder)
        mu, _ = encoder.posterior_from_inputs(inputs)
        errors[label] = reference.relae(decoder.decode_mapped(mu)).tolist()
    out = []
    for index, name in enumerate(names):
        material = materials[name]
        metal = max(material.diffuse) == 0
        colour = np.asarray(material.specular if metal else material.diffuse, dtype=float)
        hue, saturation, _ = colorsys.rgb_to_hsv(*(colour / max(colour.max(), 1e-12)))
        out.append({"material": name, "kind": "metal" if metal else "dielectric", "colour": colour.tolist(),
                    "saturation": saturation, "hue": hue, "alpha": material.roughness,
                    "mapped_relae": {label: values[index] for label, values in errors.items()}})
    sharp = np.array([row["alpha"] < SHARP_ALPHA for row in out])
    for label in MODELS:
        values = np.array([row["mapped_relae"][label] for row in out])
        print(f"{label}: all {values.mean():.4f}; α < {SHARP_ALPHA}: {values[sharp].mean():.4f} "
              f"({sharp.sum()}); α ≥ {SHARP_ALPHA}: {values[~sharp].mean():.4f} ({(~sharp).sum()})")
    write_rows(args.output, stamp(out, study="saturation-per-material", dataset=DATASET, models=MODELS,
                                  command="python reports/disentanglement/never_seen_per_material.py"))


if __name__ == "__main__":
    main()
