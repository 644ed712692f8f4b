"""Mapped RelAE of a training run's ``best.pt`` per family and split, at the encoder's code (effort 0).

Usage: ``python reports/model-v2-trials/family_eval.py RUN_DIR DATASET.h5`` prints one JSON list, a row per
(family, split) of the dataset: the mean full-table mapped RelAE (``spec/conventions.md`` §8) of
``decoder(μ(x))``, as training's validation measures it (no export, no float16 round trip of the weights). Runs on
the GPU when there is one. Used for the GPU sweep of ``README.md`` here, where `bvae model evaluate` (which also
renders for ΔE ITP) did not fit the machine's time.
"""

from __future__ import annotations

import json
import sys

import torch

from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.models.config import ModelConfig
from brdfcodec.models.network import BetaVAE
from brdfcodec.training.evaluation import MappedReference, reconstruct_mapped


def main(run_dir: str, dataset_path: str) -> list[dict[str, object]]:
    best = torch.load(f"{run_dir}/best.pt", map_location="cpu", weights_only=False)
    model = BetaVAE(ModelConfig.from_dict(json.loads(best["model_config"])))
    model.load_state_dict(best["model"])
    device = "cuda" if torch.cuda.is_available() else "cpu"
    model = model.to(device).eval()
    rows: list[dict[str, object]] = []
    with BrdfDataset(dataset_path) as data:
        families = sorted(set(data.families))
        for family in families:
            for split in ("train", "validation"):
                indices = data.indices(split, family=family)
                if not indices:
                    continue
                outputs = reconstruct_mapped(model, data.inputs(indices), device=device)
                errors = MappedReference(data, indices).relae(outputs)
                rows.append({"family": family, "split": split, "count": len(indices),
                             "mapped": float(errors.mean()), "best_epoch": best["epoch"]})
    return rows


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: family_eval.py RUN_DIR DATASET.h5")
    print(json.dumps(main(sys.argv[1], sys.argv[2])))
