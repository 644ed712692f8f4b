"""Score finished training runs where they trained: disentanglement (MIG, DCI on the benchmark's 300 analytic
materials of seed 0, as ``bvae model disentanglement``) and reconstruction (mapped RelAE of decoder(μ(x)) on the
full tables of every dataset material, per family, as ``bvae model export`` measures it). One JSON line per run;
each run's ``best.pt`` is also written slim (``slim.pt``, 15.5 MB instead of 34 MB: the encoder's linear path left
out, as a compact model folder leaves it out, and its fully connected layer in float16, as a compact folder
stores it), for the device tool's 16 MB files. ``restore_runs.py`` rebuilds ``best.pt`` from it.

usage: python score_runs.py DATASET BENCH_NPZ OUT_JSONL RUN_DIR [RUN_DIR ...]
       python score_runs.py --bench-only BENCH_NPZ    (tabulate the benchmark's materials once, for the runs)
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from brdfcodec.datasets.analytic import sample_factor_materials
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.models.config import ModelConfig
from brdfcodec.models.network import BetaVAE
from brdfcodec.report.disentanglement import benchmark_inputs, score_code
from brdfcodec.training.checkpoint import load_checkpoint
from brdfcodec.training.evaluation import MappedReference, reconstruct_mapped


def bench(path: Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The benchmark's inputs (300, 63, 90, 90), factors and factor names; the inputs cached in ``path``."""
    if path.exists():
        data = np.load(path)
        drawn = sample_factor_materials(300, seed=0)
        return data["inputs"], drawn.factors, list(drawn.names)
    drawn, inputs, _ = benchmark_inputs(300, 0)
    np.savez(path, inputs=inputs)
    return inputs, drawn.factors, list(drawn.names)


def main() -> int:
    if sys.argv[1:2] == ["--bench-only"]:
        bench(Path(sys.argv[2]))
        return 0
    dataset_path, bench_path, out_path, *runs = sys.argv[1:]
    device = "cuda" if torch.cuda.is_available() else "cpu"
    inputs, factors, names = bench(Path(bench_path))
    with BrdfDataset(dataset_path) as dataset:
        indices = list(range(len(dataset)))
        families = list(dataset.families)
        data_inputs = dataset.inputs(indices)
        reference = MappedReference(dataset, indices)
    for run in map(Path, runs):
        start = time.perf_counter()
        row = {"run": run.name}
        try:
            state = load_checkpoint(run / "best.pt", required={"model": dict, "epoch": int, "model_config": str})
            model = BetaVAE(ModelConfig.from_dict(json.loads(state["model_config"])))
            model.load_state_dict(state["model"])
            model = model.to(device).eval()
            with torch.no_grad():
                codes = []
                for s in range(0, len(inputs), 32):
                    mu, _ = model.encoder(torch.from_numpy(inputs[s:s + 32]).to(device))
                    codes.append(mu.float().cpu().numpy())
            scores = score_code(np.concatenate(codes), factors, names)
            errors = reference.relae(reconstruct_mapped(model, data_inputs, device=device))
            per_family = {family: float(np.mean([e for e, g in zip(errors, families, strict=True) if g == family]))
                          for family in sorted(set(families))}
            row.update(epoch=state["epoch"], mig=scores.mig, dci_d=scores.disentanglement,
                       dci_c=scores.completeness, dci_i=scores.informativeness, r2=scores.r2_per_factor,
                       dominant=scores.dominant_factor, relae_all=float(np.mean(errors)), relae=per_family,
                       seconds=time.perf_counter() - start)
            derived = ("encoder.basis_mean", "encoder.basis_projection")  # rebuilt from the decoder's on restoring
            slim = {k: v for k, v in state["model"].items() if k not in derived}
            slim["encoder.fc.0.weight"] = slim["encoder.fc.0.weight"].half()
            torch.save({"model": slim, "epoch": state["epoch"], "model_config": state["model_config"]}, run / "slim.pt")
        except Exception as error:  # a broken run is a row, the others go on
            row["error"] = f"{type(error).__name__}: {error}"
        print(json.dumps(row), flush=True)
        with open(out_path, "a") as out:
            out.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
