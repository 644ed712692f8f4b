"""Collect a from-scratch training study of issue 50 item 3 (trained on a device) into one rows file.

usage (repository root; the runs restored by benchmarks/device/training/restore_runs.py into runs/SESSION, the
models exported into runs/models/SESSION-NAME, the measurements of the study's text header in runs/SESSION/eval):

    python reports/disentanglement/from_scratch_rows.py [--study from-scratch-supervision | free-dimensions |
        saturation | cpu-fold2 | rate-fold2 | swa-fold2 | latent-size-fold2 | rate-prior-fold2 |
        encoder-refit-fold2 | mean-recon-fold2 | mean-recon-scratch-fold2 | factor-weight-scratch-fold2]

Studies: ``from-scratch-supervision`` (runs/dev1: four factor weights, one H100, time-limited),
``free-dimensions`` (runs/dev2: weights 5,000 and 10,000 and a 12-dimensional latent, one H200, full schedules) and
``saturation`` (runs/dev3: the colour's saturation as an eighth factor; weights 10,000 and 5,000, and 10,000 with
half the analytic materials per step; one H200, full schedules; scored on the device on never-seen analytic
materials too) and ``cpu-fold2`` (runs/cpu21: issues 48 and 50 with one training, on this machine's CPU, one run per
core; fold 2 of 3, so that reconstruction is measured on materials the models never saw, beside the v3 recipe's
fold-2 model re-made here) and ``rate-fold2`` (runs/q22: issue 48 item 3, the v3 recipe's fold-2 model trained on
the coded μ's grid, with and without the codec's rate in its loss; reconstruction with μ exact and on the grid)
and ``swa-fold2`` (runs/s24: cpu-fold2's supervised 16-dimensional recipe with stochastic weight averaging at three
factor weights; reconstruction also at the codec's encoder effort) and ``latent-size-fold2`` (runs/s25: the
supervised recipe with 1 and 2 free dimensions; μ on the coded grids 2^-1, 2^-2 and 2^-3 and its bytes; file
bytes) and ``rate-prior-fold2`` (runs/s26: μ's bytes under per-dimension priors fitted to the training materials,
and the supervised 16-dimensional recipe trained with a rate term) and ``encoder-refit-fold2`` (runs/s28: that
recipe's encoder refitted to its frozen decoder, ``bvae model refit-encoder``, for its codes at effort 0) and
``mean-recon-fold2`` (runs/s29: that recipe's fold-2 model fine-tuned with a reconstruction term at μ itself,
``bvae train --mean-recon-weight``, against the same fine-tuning without it) and ``mean-recon-scratch-fold2``
(runs/s30: that recipe trained from scratch with the term, at two weights and with doubled factor terms) and
``factor-weight-scratch-fold2`` (runs/s31: the term at weight 1 with a factor weight between, 14,000).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.report.rows import read_rows, stamp, write_rows


@dataclass(frozen=True)
class Study:
    """Where one study's runs, exports and measurements are, and how its tables are headed."""

    name: str
    session: str  # runs/SESSION, runs/models/SESSION-RUN
    runs: tuple[str, ...]
    device: str
    training_title: str
    header: str
    train_keys: tuple[str, ...] = ()  # more of each run's train_config, in its training row and line
    #: The models the runs are compared with: label → folder (the shipped model unless a study says otherwise).
    references: tuple[tuple[str, str], ...] = (("bvae-nbrdf-proxy-small-v3", "brdfcodec/data/models/default"),)
    #: Trained on one fold: reconstruction per family and split (trained on, held out) from ``bvae model evaluate
    #: MODEL --dataset runs/both.h5`` (eval/evaluate-both-FOLDER.json) in place of the export's training errors.
    fold: bool = False
    #: How a run's model is named (its exported name, as the benchmark's rows give it): prefix + run.
    prefix: str = "bvae-scratch-"
    #: The folder (in runs/SESSION) of the training whose log a run's training row reads, ``{run}`` its name: a
    #: two-stage recipe's second stage (``ft-{run}``), the run itself otherwise.
    training_folder: str = "{run}"
    #: Rows of models measured by an earlier study, copied from its committed rows: (rows file, model names).
    imported: tuple[tuple[str, tuple[str, ...]], ...] = ()
    #: Models trained on every material whose encoder a study refitted, with the model refitted: label → folder,
    #: reported by their training error (the export's) beside the refit.
    refit_references: tuple[tuple[str, str], ...] = ()

    @property
    def folder(self) -> Path:
        return Path("runs") / self.session

    @property
    def models(self) -> dict[str, str]:
        return {**dict(self.references),
                **{f"{self.prefix}{run}": f"runs/models/{self.session}-{run}" for run in self.runs}}


def _run_files(run: Path) -> tuple[list[dict], dict, dict]:
    """A `bvae train` run folder's epoch log, summary and run description."""
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines() if line.strip()]
    return log, json.loads((run / "summary.json").read_text()), json.loads((run / "run.json").read_text())


def training_rows(study: Study) -> list[dict]:
    if not (study.folder / "device-logs").exists():
        return _local_training_rows(study)
    rows = []
    runs = study.folder
    scored = {json.loads(line)["run"]: json.loads(line)
              for line in (runs / "device-logs/logs/eval.jsonl").read_text().splitlines() if line.strip()}
    plan = {line.split()[0]: line.split()[1:] for line in (runs / "device-logs/logs/plan.txt").read_text().splitlines()}
    for name, score in sorted(scored.items()):
        log, summary, described = _run_files(runs / name)
        config = described["train_config"]
        rows.append({
            "kind": "training", "model": f"{study.prefix}{name}", "device": study.device, "torch": "2.11.0+cu130",
            "command": (runs / f"cmd-{name}.txt").read_text().strip(), "factor_weight": config["factor_weight"],
            "epochs_planned": int(plan[name][0]), "epochs_done": summary["epochs_done"],
            "weights_epoch": score["epoch"], "stop_reason": summary["stop_reason"],
            "seconds": summary["seconds_this_session"], "seconds_per_epoch_probe": float(plan[name][2]),
            "last_epoch": {k: log[-1][k] for k in ("lr", "recon", "kl", "traversal", "factor")},
            "device_scores": {k: score[k] for k in ("mig", "dci_d", "dci_c", "dci_i", "relae_all", "relae")},
            **{k: config[k] for k in study.train_keys},
        })
    return rows


def _local_training_rows(study: Study) -> list[dict]:
    """Training rows of runs made on this machine (no device logs): each run's own summary, log and settings."""
    rows = []
    for name in study.runs:
        log, summary, described = _run_files(study.folder / study.training_folder.format(run=name))
        config = described["train_config"]
        rows.append({
            "kind": "training", "model": f"{study.prefix}{name}", "device": study.device,
            "torch": described["torch_version"], "command": (study.folder / f"cmd-{name}.txt").read_text().strip(),
            "factor_weight": config["factor_weight"], "latent_dim": described["model_config"]["latent_dim"],
            "epochs_planned": config["epochs"], "epochs_done": summary["epochs_done"],
            "weights_epoch": log[-1]["epoch"], "stop_reason": summary["stop_reason"],
            "seconds": summary["seconds_this_session"],
            "seconds_per_epoch": sum(r["seconds"] for r in log) / len(log),
            "last_epoch": {k: log[-1][k] for k in ("lr", "recon", "kl", "traversal", "factor", "rate_bits")
                           if k in log[-1]},
            "held_out_relae_mapped": log[-1].get("val_relae_mapped"),
            **{k: config[k] for k in study.train_keys},
        })
    return rows


#: The datasets a fold study's models are evaluated on: the two families (runs/both.h5: the fold's training and
#: held-out materials) and 24 random analytic materials none of the models saw (``bvae dataset build --random 24
#: -o runs/random24.h5``, seed 0: the analytic ones of runs/v3-held-out.h5).
FOLD_DATASETS = {"both": "runs/both.h5", "random": "runs/random24.h5"}

#: μ rounded to a grid before it is decoded (``bvae model evaluate --mu-grid G``, eval/evaluate-both-gridG-FOLDER.json):
#: the latent as a record's coded μ stores it, on the grids 2^-1, 2^-2 (that of most 16 B records) and 2^-3, where a
#: study measured them.
GRID_EVALUATIONS = tuple((f"both-grid{grid}", "runs/both.h5", grid) for grid in (1, 2, 3))

#: The same datasets encoded at the codec's default effort (``bvae model evaluate --effort 1``: μ refined through the
#: decoder, as ``bvae compress`` encodes; eval/evaluate-KEY-e1-FOLDER.json), where a study measured them.
EFFORT_EVALUATIONS = tuple((f"{key}-e1", dataset, 1) for key, dataset in FOLD_DATASETS.items())


def _fold_rows(study: Study, name: str, folder: str) -> list[dict]:
    """A fold model's reconstruction per family and split, from ``bvae model evaluate`` (eval/evaluate-KEY-FOLDER.json
    for each dataset of :data:`FOLD_DATASETS`, and of :data:`GRID_EVALUATIONS` and :data:`EFFORT_EVALUATIONS` where a
    study measured them)."""
    rows = []
    runs = [*((k, d, None, 0) for k, d in FOLD_DATASETS.items()), *((*grid, 0) for grid in GRID_EVALUATIONS),
            *((k, d, None, effort) for k, d, effort in EFFORT_EVALUATIONS)]
    for key, dataset, grid, effort in runs:
        path = study.folder / "eval" / f"evaluate-{key}-{Path(folder).name}.json"
        if path.exists() and path.stat().st_size:
            option = ("" if grid is None else f" --mu-grid {grid}") + (f" --effort {effort}" if effort else "")
            rows += [{"kind": "evaluation", "model": name, **row, "dataset": dataset, "effort": effort,
                      "command": f"bvae model evaluate {folder} --dataset {dataset}{option} --json"}
                     for row in json.loads(path.read_text())]
    return rows


def training_error_rows(name: str, folder: str, family: dict[str, str]) -> list[dict]:
    """A model's training error per family: the mean of its export's per-material errors (``info.errors``)."""
    per: dict[str, list[dict]] = {}
    for error in json.loads(Path(folder, "model.json").read_text())["info"]["errors"]:
        per.setdefault(family[error["name"]], []).append(error)
    return [{"kind": "reconstruction", "model": name, "family": fam, "split": "train", "count": len(errors),
             "effort": 0, "relae_mapped": sum(e["relae_mapped"] for e in errors) / len(errors),
             "relae_linear": sum(e["relae_linear"] for e in errors) / len(errors),
             "command": "bvae model export (model.json info.errors: μ of the encoder decoded, mapped RelAE on the "
                        "full table of each of the 120 materials of runs/both.h5)"}
            for fam, errors in sorted(per.items())]


def reconstruction_rows(study: Study) -> list[dict]:
    with BrdfDataset("runs/both.h5") as dataset:
        family = dict(zip(dataset.names, dataset.families, strict=True))
    rows = []
    evaluations = study.folder / "eval"
    for name, folder in study.models.items():
        if study.fold:
            rows += _fold_rows(study, name, folder)
            continue
        rows += training_error_rows(name, folder, family)
        held_out = evaluations / f"evaluate-{Path(folder).name}.json"
        if held_out.exists() and held_out.stat().st_size:
            for row in json.loads(held_out.read_text()):
                rows.append({"kind": "evaluation", "model": name, **row, "effort": 0,
                             "command": f"bvae model evaluate {folder} --dataset runs/v3-held-out.h5 --json"})
    probe_rows = evaluations / "refine_probe.jsonl"
    for line in (probe_rows.read_text().splitlines() if probe_rows.exists() else []):
        probe = json.loads(line)
        label = {"v3": "bvae-nbrdf-proxy-small-v3"}.get(probe["model"], f"bvae-scratch-{probe['model']}")
        rows.append({"kind": "refinement", **probe, "model": label,
                     "command": "python reports/disentanglement/refinement_probe.py "
                                "> runs/dev1/eval/refine_probe.jsonl "
                                "(BrdfEncoder(effort=E).encode, decode, mapped RelAE on the full table; every 4th "
                                "of the 120 materials of runs/both.h5)"})
    return rows


FROM_SCRATCH_SUPERVISION = Study(
    name="from-scratch-supervision", session="dev1", runs=("w0", "w3k", "w10k", "w30k"),
    device="cuda: NVIDIA H100 80GB HBM3 (driver 580.159.04), four runs side by side",
    training_title="Training (one H100, four runs side by side):",
    header="""\
# Factor supervision from scratch (issue 50 item 3): four models of the release recipe trained side by side on one
# NVIDIA H100 (torch 2.11.0+cu130), all 120 materials of the NBRDF proxies (90 MERL, 30 RGL; neural fits, not
# measurements), each `bvae train` run stopped by the session's time limit (epochs below), weights of its last
# evaluation. Runner: benchmarks/device/training/train_side_by_side.sh (configs: from-scratch-supervision.configs).
# Export here: bvae model export runs/dev1/RUN -o runs/models/dev1-RUN --name bvae-scratch-RUN --dataset runs/both.h5
#   --basis-count 0 --align-factors 300 --keep-axes (axes as trained; no shared basis: measured, not shipped)
# Benchmark: bvae model disentanglement brdfcodec/data/models/default runs/models/dev1-{w0,w3k,w10k,w30k}
#   --materials 300 --seed S (S = 0, as reports/disentanglement/default-model.txt, and 2)
# Never-seen materials: bvae model evaluate MODEL --dataset runs/v3-held-out.h5 (24 random analytic, 1 real RGL)
# Rows: python reports/disentanglement/from_scratch_rows.py -> from-scratch-supervision.jsonl
""")

FREE_DIMENSIONS = Study(
    name="free-dimensions", session="dev2", runs=("w5k-z8", "w10k-z8", "w10k-z12"),
    device="cuda: NVIDIA H200 (driver 580.159.04), three runs side by side",
    training_title="Training (one H200, three runs side by side):",
    header="""\
# Free latent dimensions beside the supervised ones (issue 50 item 3): three models of the release recipe trained
# from scratch side by side on one NVIDIA H200 (torch 2.11.0+cu130), all 120 materials of the NBRDF proxies (90
# MERL, 30 RGL; neural fits, not measurements), each to the end of its planned schedule (epochs below): factor weight
# 5,000 and 10,000 with an 8-dimensional latent, and 10,000 with a 12-dimensional one whose dimensions 8-12 no
# factor pulls. Runner: benchmarks/device/training/train_side_by_side.sh (configs: free-dimensions.configs).
# Export here: bvae model export runs/dev2/RUN -o runs/models/dev2-RUN --name bvae-scratch-RUN --dataset runs/both.h5
#   --basis-count 0 --align-factors 300 --keep-axes (axes as trained; no shared basis: measured, not shipped)
# Benchmark: bvae model disentanglement brdfcodec/data/models/default runs/models/dev2-{w5k-z8,w10k-z8,w10k-z12}
#   --materials 300 --seed S (S = 0, as reports/disentanglement/default-model.txt, and 2)
# Never-seen materials: bvae model evaluate MODEL --dataset runs/v3-held-out.h5 (24 random analytic, 1 real RGL)
# Rows: python reports/disentanglement/from_scratch_rows.py --study free-dimensions -> free-dimensions.jsonl
""")

SATURATION = Study(
    name="saturation", session="dev3", runs=("sat-w10k", "sat-w5k", "sat-w10k-fb4"),
    device="cuda: NVIDIA H200 (driver 580.159.04), three runs side by side",
    training_title="Training (one H200, three runs side by side):",
    train_keys=("factor_batch", "factor_saturation"),
    header="""\
# The colour's saturation as a factor of the supervision (issue 50 item 3): the supervised models of
# free-dimensions.txt decoded 24 never-seen random analytic materials about twice as badly as the shipped model, and
# every colour of their factor pool had one saturation (0.7), so grey and white materials were outside the family
# the supervision tied the latent to. `bvae train --factor-saturation` (commit 673e319) draws the pool's saturation
# from grey to fully saturated as an eighth factor tied to dimension 8, the hue term weighted by min(1, s / 0.7).
# Three models of the release recipe trained from scratch side by side on one NVIDIA H200 (torch 2.11.0+cu130), all
# 120 materials of the NBRDF proxies (90 MERL, 30 RGL; neural fits, not measurements), each to the end of its planned
# schedule (epochs below): factor weight 10,000 and 5,000, and 10,000 with 4 analytic materials per step instead of
# 8 (--factor-batch 4). Runner: benchmarks/device/training/train_side_by_side.sh (configs: saturation.configs;
# SCORE_SOURCES="--random 24": also scored on the device on 24 random analytic materials none of them saw).
# Export here: bvae model export runs/dev3/RUN -o runs/models/dev3-RUN --name bvae-scratch-RUN --dataset runs/both.h5
#   --basis-count 0 --align-factors 300 --keep-axes (axes as trained; no shared basis: measured, not shipped)
# Benchmark: bvae model disentanglement brdfcodec/data/models/default runs/models/dev3-{sat-w10k,sat-w5k,sat-w10k-fb4}
#   --materials 300 --seed S (S = 0, as reports/disentanglement/default-model.txt, and 2); its materials have seven
#   factors at saturation 0.7, so no benchmark factor measures dimension 8
# Never-seen materials: bvae model evaluate MODEL --dataset runs/v3-held-out.h5 (24 random analytic, 1 real RGL);
#   "analytic 24 (device)": the device's score, the same mapped RelAE of its dataset's 24 random analytic materials
# Rows: python reports/disentanglement/from_scratch_rows.py --study saturation -> saturation.jsonl
""")

#: The machine of the studies trained on this machine's CPU, and their training table's title.
CPU_PAIR = "cpu: 2 cores (x86_64, torch 2.13.0+cpu), one run per core (OMP_NUM_THREADS=1), two side by side"
CPU_PAIR_TITLE = "Training (this machine's CPU, one run per core, two side by side):"
#: cpu-fold2's v3 baseline and its supervised runs with 8, 12 and 16 dimensions: the references of later fold-2 studies.
CPU21_SUPERVISED_REFERENCES = (("bvae-cv3-fold2-v3", "runs/models/cpu21-cv3-fold2-v3"),
                               ("bvae-cpu21-f2-sharp-w10k-z8", "runs/models/cpu21-f2-sharp-w10k-z8"),
                               ("bvae-cpu21-f2-sharp-w10k-z12", "runs/models/cpu21-f2-sharp-w10k-z12"),
                               ("bvae-cpu21-f2-sharp-w10k-z16", "runs/models/cpu21-f2-sharp-w10k-z16"))

CPU_FOLD2 = Study(
    name="cpu-fold2", session="cpu21", runs=("f2-w0", "f2-sharp-w10k-z8", "f2-sharp-w10k-z12", "f2-sharp-w10k-z16",
                                         "f2-v3-sharp-w10k-z16"),
    device=CPU_PAIR,
    training_title=CPU_PAIR_TITLE,
    train_keys=("factor_saturation", "factor_alpha_min"),
    references=(("bvae-nbrdf-proxy-small-v3", "brdfcodec/data/models/default"),
                ("bvae-cv3-fold2-v3", "runs/models/cpu21-cv3-fold2-v3")),
    fold=True, prefix="bvae-cpu21-",
    header="""\
# Issues 48 and 50 with one training, on fold 2 of 3 (the rd benchmark's 40 held-out materials: 30 MERL, 10 RGL),
# trained from scratch on this machine's 2-core CPU (no device was lent), one run per core, two at a time: the
# release recipe for 400 epochs without supervision (f2-w0), and with dimensions 1-8 tied to the analytic factors
# (weight 10,000, the colour's saturation an eighth factor, GGX alpha of the factor pool from 0.01) beside 0, 4 and 8
# free dimensions (f2-sharp-w10k-z8, -z12, -z16; benchmarks/device/training/fold2-codec-and-factors.configs holds
# f2-w0, -z12 and -z16 as a device's runs); and the 16-dimensional supervision inside the v3 recipe's two stages
# instead (f2-v3-sharp-w10k-z16: 150 epochs with the any-direction penalty at weight 10, then 60 with the axis
# penalty, no alignment; its training row is the second stage's, both stages' commands in it).
# Baseline: the v3 recipe's fold-2 model re-made here (bvae-cv3-fold2-v3: benchmarks/rd/README.md's recipe, its
# stage-one export without a basis; the shipped model, trained on all 120, is listed for the benchmark and the
# never-seen analytic materials only: it saw every material of both families).
# NBRDF proxies (90 MERL, 30 RGL; neural fits, not measurements); analytic: 24 random materials none saw.
# Commands: runs/cpu21/cmd-RUN.txt (in the training rows); export here: bvae model export runs/cpu21/RUN
#   -o runs/models/cpu21-RUN --name bvae-cpu21-RUN --dataset runs/both.h5 --align-factors 300 --keep-axes, then
#   bvae model fit-basis runs/models/cpu21-RUN --dataset runs/both.h5 --count 200 --extend
# Benchmark: bvae model disentanglement MODELS --materials 300 --seed S (S = 0 and 2)
# Reconstruction: bvae model evaluate MODEL --dataset runs/both.h5 (and runs/random24.h5) --json
# File bytes against the best PCA: reports/results/rd-cpu21-fold2-*.jsonl (benchmarks/rd/cpu21-fold2-*.json)
# Rows: python reports/disentanglement/from_scratch_rows.py --study cpu-fold2 -> cpu-fold2.jsonl
""")

RATE_FOLD2 = Study(
    name="rate-fold2", session="q22", runs=("g2", "g2r70", "g2r300", "g2r1000", "g2r3000", "g2r10000"),
    device=CPU_PAIR,
    training_title="Training (this machine's CPU, one run per core, two side by side; the second stage's log):",
    train_keys=("latent_grid", "rate_weight"),
    references=(("bvae-cv3-fold2-v3", "runs/models/cpu21-cv3-fold2-v3"),),
    fold=True, prefix="bvae-q22-", training_folder="ft-{run}",
    header="""\
# Issue 48 item 3, a rate term in training, on fold 2 of 3 (the rd benchmark's 40 held-out materials: 30 MERL, 10
# RGL): the v3 recipe's fold-2 model (benchmarks/rd/README.md; 150 epochs, export with --align-factors 300, then 60
# epochs of the axis penalty and an export with --keep-axes) trained in both stages with z + uniform noise of width
# 2^-2 (bvae train --latent-grid 2: the rounding of a record's coded μ on the grid 2^-2, the grid of most 16 B
# records), without a rate (g2) and with lambda times μ's code length on that grid under the format's unit Laplace
# prior added to the loss (--rate-weight lambda: g2r70, g2r300, g2r1000, g2r3000, g2r10000).
# Baseline: the v3 recipe's fold-2 model re-made on this machine without the noise (bvae-cv3-fold2-v3, runs/cpu21).
# NBRDF proxies (90 MERL, 30 RGL; neural fits, not measurements); analytic: 24 random materials none saw.
# Commands: both stages, the exports and bvae model fit-basis --count 200 --extend in the training rows
#   (runs/q22/cmd-RUN.txt)
# Reconstruction: bvae model evaluate MODEL --dataset runs/both.h5 [--mu-grid 2] (and runs/random24.h5) --json
# File bytes against the best PCA: reports/results/rd-q22-fold2-*.jsonl (benchmarks/rd/q22-fold2-*.json)
# Rows: python reports/disentanglement/from_scratch_rows.py --study rate-fold2 -> rate-fold2.jsonl
""")

SWA_FOLD2 = Study(
    name="swa-fold2", session="s24", runs=("z16-swa200", "z16-e250-swa125", "z16-w7k-swa200", "z16-w5k-swa200",
          "z16-w5k-swa200-seed1"),
    device=CPU_PAIR,
    training_title=CPU_PAIR_TITLE,
    train_keys=("average_from_epoch",),
    references=CPU21_SUPERVISED_REFERENCES,
    fold=True, prefix="bvae-s24-",
    header="""\
# Issue 50 item 3 on fold 2 of 3 (the rd benchmark's 40 held-out materials: 30 MERL, 10 RGL): cpu-fold2's supervised
# 16-dimensional recipe (f2-sharp-w10k-z16: the release recipe, 400 epochs, dimensions 1-8 tied to the analytic factors,
# the colour's saturation an eighth factor, GGX alpha of the factor pool from 0.01, 8 free dimensions) with the weights
# averaged over every step of the schedule's second half (bvae train --average-from-epoch): at factor weight 10,000 over
# 400 epochs averaged from 200 (z16-swa200) and over 250 averaged from 125 (z16-e250-swa125), and at weights 7,000 and
# 5,000 (z16-w7k-swa200, z16-w5k-swa200; 400 epochs, averaged from 200; the 5,000 run again with training seed 1,
# z16-w5k-swa200-seed1). References: cpu-fold2's runs of the recipe at 10,000 without the average (last weights; 8, 12
# and 16 dimensions), and the v3 recipe's fold-2 model (bvae-cv3-fold2-v3, the baseline of issue 50's "no worse on
# every family"). Reconstruction is measured twice: μ of the encoder (effort 0, what training measures) and μ refined
# through the decoder (effort 1, bvae compress's default: what a user's file holds).
# NBRDF proxies (90 MERL, 30 RGL; neural fits, not measurements); analytic: 24 random materials none saw.
# Commands: runs/s24/cmd-RUN.txt (in the training rows; a later --factor-weight overrides the first); export here:
#   bvae model export runs/s24/RUN -o runs/models/s24-RUN --name bvae-s24-RUN --dataset runs/both.h5
#   --align-factors 300 --keep-axes
# Benchmark: bvae model disentanglement MODEL --materials 300 --seed S --no-pca (S = 0 and 2); the references' rows
#   are cpu-fold2's
# Reconstruction: bvae model evaluate MODEL --dataset runs/both.h5 (and runs/random24.h5) [--effort 1] --json;
#   μ on the coded grid of most 16 B records and its bytes: bvae model evaluate MODEL --dataset runs/both.h5
#   --mu-grid 2 --json (five of the models)
# File bytes against the best PCA (weights 5,000 and 7,000, basis grown with bvae model fit-basis --count 200
#   --extend): reports/results/rd-s24-fold2-*.jsonl (benchmarks/rd/s24-fold2-*.json)
# Rows: python reports/disentanglement/from_scratch_rows.py --study swa-fold2 -> swa-fold2.jsonl
""")

LATENT_SIZE_FOLD2 = Study(
    name="latent-size-fold2", session="s25", runs=("z9", "z10", "z10-seed1"),
    device=CPU_PAIR,
    training_title=CPU_PAIR_TITLE,
    references=CPU21_SUPERVISED_REFERENCES,
    fold=True, prefix="bvae-s25-",
    header="""\
# Issues 48 and 50 on fold 2 of 3 (the rd benchmark's 40 held-out materials: 30 MERL, 10 RGL): how many free dimensions
# the supervised recipe needs, and what each costs a record's coded μ. cpu-fold2's recipe (the release recipe, 400
# epochs, dimensions 1-8 tied to the analytic factors at weight 10,000, the colour's saturation an eighth factor, GGX
# alpha of the factor pool from 0.01, last weights) with 1 and 2 free dimensions (z9, z10; z10 again with training seed
# 1, z10-seed1), beside cpu-fold2's runs with 0, 4 and 8 (z8, z12, z16) and the v3 recipe's fold-2 model
# (bvae-cv3-fold2-v3, the baseline of issue 50's "no worse on every family"). μ is measured as a record stores it too:
# rounded to the coded grids 2^-1, 2^-2 and 2^-3 (bvae model evaluate --mu-grid G; the codec's records of at most 32 B
# take 2^-2 or 2^-3), with its bytes coded alone under the format's unit prior.
# NBRDF proxies (90 MERL, 30 RGL; neural fits, not measurements); analytic: 24 random materials none saw.
# Commands: runs/s25/cmd-RUN.txt (in the training rows); export here: bvae model export runs/s25/RUN
#   -o runs/models/s25-RUN --name bvae-s25-RUN --dataset runs/both.h5 --align-factors 300 --keep-axes
# Benchmark: bvae model disentanglement MODEL --materials 300 --seed S --no-pca (S = 0 and 2); the references' rows
#   are cpu-fold2's
# Reconstruction: bvae model evaluate MODEL --dataset runs/both.h5 (and runs/random24.h5) [--effort 1] --json;
#   bvae model evaluate MODEL --dataset runs/both.h5 --mu-grid G --json (G = 1, 2, 3; z10-seed1: 2)
# File bytes against the best PCA (z9, z10; basis grown with bvae model fit-basis --count 200 --extend):
#   reports/results/rd-s25-fold2-*.jsonl (benchmarks/rd/s25-fold2-*.json)
# Rows: python reports/disentanglement/from_scratch_rows.py --study latent-size-fold2 -> latent-size-fold2.jsonl
""")

RATE_PRIOR_FOLD2 = Study(
    name="rate-prior-fold2", session="s26", runs=("z16r1000", "z16r3000"),
    device=CPU_PAIR,
    training_title=CPU_PAIR_TITLE,
    train_keys=("latent_grid", "rate_weight"),
    references=(*CPU21_SUPERVISED_REFERENCES, ("bvae-s25-z9", "runs/models/s25-z9"),
                ("bvae-s25-z10", "runs/models/s25-z10")),
    fold=True, prefix="bvae-s26-",
    header="""\
# Issues 48 and 50 on fold 2 of 3 (the rd benchmark's 40 held-out materials: 30 MERL, 10 RGL): would a prior for μ
# per latent dimension, fitted to the model's training materials, let a supervised latent with free dimensions cost a
# record no more than the v3 latent? Under the format's unit prior (§4.9) a dimension of a coded μ at 0 still costs
# about 2.6 bits (ideal) on the grid 2^-2, however little it varies. Two measures: (1) each model's μ on the coded
# grids priced under per-dimension Laplace priors fitted to its 80 training materials' μ on the same grid (bvae model
# evaluate --mu-grid G: mu_bytes_fitted, mu_prior_codes; the held-out materials priced under the fit), the models of
# latent-size-fold2 and cpu-fold2 as references; (2) cpu-fold2's supervised 16-dimensional recipe (400 epochs,
# dimensions 1-8 tied to the analytic factors at weight 10,000, the colour's saturation an eighth factor, GGX alpha
# of the factor pool from 0.01, last weights) trained with z + uniform noise of width 2^-2 and lambda times μ's code
# length under the unit prior (bvae train --latent-grid 2 --rate-weight lambda, lambda = 1,000 and 3,000: an L1
# pull that can leave the free dimensions at 0 for most materials, which a fitted prior then prices near 0 bits).
# NBRDF proxies (90 MERL, 30 RGL; neural fits, not measurements); analytic: 24 random materials none saw.
# Commands: runs/s26/cmd-RUN.txt (in the training rows); export here: bvae model export runs/s26/RUN
#   -o runs/models/s26-RUN --name bvae-s26-RUN --dataset runs/both.h5 --align-factors 300 --keep-axes
# Benchmark: bvae model disentanglement MODEL --materials 300 --seed S --no-pca (S = 0 and 2); the references' rows
#   are cpu-fold2's and latent-size-fold2's
# Reconstruction: bvae model evaluate MODEL --dataset runs/both.h5 (and runs/random24.h5) [--effort 1] --json;
#   bvae model evaluate MODEL --dataset runs/both.h5 --mu-grid G --json (G = 2; 3 for some)
# File bytes against the best PCA (z16r1000, z16r3000; basis grown with bvae model fit-basis --count 200 --extend):
#   reports/results/rd-s26-fold2-*.jsonl (benchmarks/rd/s26-fold2-*.json)
# Rows: python reports/disentanglement/from_scratch_rows.py --study rate-prior-fold2 -> rate-prior-fold2.jsonl
""")

ENCODER_REFIT_FOLD2 = Study(
    name="encoder-refit-fold2", session="s28", runs=("z16r1000",),
    device="cpu: 2 cores (x86_64, torch 2.13.0+cpu), OMP_NUM_THREADS=1, beside the session's other work",
    training_title="Training (this machine's CPU, one core):",
    train_keys=("latent_grid", "rate_weight"),
    references=(("bvae-cv3-fold2-v3", "runs/models/cpu21-cv3-fold2-v3"),
                ("bvae-s26-z16r1000", "runs/models/s26-z16r1000"),
                ("bvae-s28-z16r1000-refit", "runs/models/s28-z16r1000-refit"),
                ("bvae-s28-z16r1000-refit-aug", "runs/models/s28-z16r1000-refit-aug"),
                ("bvae-s28-z16r1000-refit-aug2", "runs/models/s28-z16r1000-refit-aug2"),
                ("bvae-s28-z16r1000-refit-fw", "runs/models/s28-z16r1000-refit-fw"),
                ("bvae-s28-z16r1000-refit-free", "runs/models/s28-z16r1000-refit-free"),
                ("bvae-s28-z16r1000-refit-fw3k", "runs/models/s28-z16r1000-refit-fw3k"),
                ("bvae-s28-z16r1000-refit-blend", "runs/models/s28-z16r1000-refit-blend"),
                ("bvae-s28-z16r1000-refit-wide", "runs/models/s28-z16r1000-refit-wide")),
    refit_references=(("bvae-nbrdf-proxy-small-v3", "brdfcodec/data/models/default"),
                      ("bvae-nbrdf-proxy-small-v3-refit", "runs/models/s28-v3-refit")),
    imported=(("reports/disentanglement/rate-prior-fold2.jsonl", ("bvae-cv3-fold2-v3", "bvae-s26-z16r1000")),),
    fold=True, prefix="bvae-s28-",
    header="""\
# Issue 50, "held-out reconstruction no worse than today's model's, as in bvae model evaluate" (effort 0, the
# encoder's μ): the editing recipe's fold-2 model decodes its encoder's μ worse than the v3 recipe's on MERL and on
# analytic materials (rate-prior-fold2.txt), while at effort 1 (μ refined through the decoder) it is no worse. The
# gap is the encoder's: trained under β·KL, the rate term and the factor terms, its μ is not the code its decoder
# reconstructs a material best from. bvae model refit-encoder trains the encoder alone, the decoder frozen (its hash
# and every file unchanged), to minimise the masked mapped L1 of decoder(μ(x)) over the model's own 80 training
# materials, with analytic materials drawn for the refit (256) in every step whose μ the model's own factor terms
# (weight 10,000) hold on their factors, as in training (the benchmark scores that μ). Four ways (each refit's row
# gives its settings): -refit, the training materials as they are (--mix-probability 0 --no-colour-permutations),
# 2 analytic materials a step, 60 epochs at learning rate 1e-4; -refit-aug, colour-permuted and a quarter blended,
# otherwise the same; -refit-aug2, half blended, 120 epochs at 2e-4; -refit-fw, as -refit-aug with 8 analytic
# materials a step, as many as the real ones (--analytic-batch 8, the default since). Then two levers on -refit-fw's
# analytic materials at effort 0 (session 29): -refit-free, the dimensions beyond the 8 factors no longer held at 0
# for them (--free-dimension-weight 0), and -refit-fw3k, the factor terms at 3,000 (--factor-weight 3000); and two
# with more varied inputs: -refit-blend, three quarters of the training materials blended (--mix-probability 0.75),
# and -refit-wide, 1,024 analytic materials drawn for the refit (--analytic-materials 1024); each otherwise
# -refit-fw's settings (its row gives them; refit and measurements: the commands below). And the shipped
# default model (v3, trained on all 120, no factor terms) refitted with the defaults: bvae model refit-encoder
# brdfcodec/data/models/default --dataset runs/both.h5 -o runs/models/s28-v3-refit (its training error below).
# Fold 2 of 3 (the rd benchmark's 40 held-out materials: 30 MERL, 10 RGL). The editing recipe is trained again here
# (bvae-s28-z16r1000, the command of rate-prior-fold2's bvae-s26-z16r1000, whose model was lost with its machine;
# its rows and the v3 recipe's, bvae-cv3-fold2-v3, are copied from rate-prior-fold2.jsonl), then refitted.
# NBRDF proxies (90 MERL, 30 RGL; neural fits, not measurements); analytic: 24 random materials none saw.
# Commands: runs/s28/cmd-z16r1000.txt (in the training row); export here: bvae model export runs/s28/z16r1000
#   -o runs/models/s28-z16r1000 --name bvae-s28-z16r1000 --dataset runs/both.h5 --basis-count 0 --align-factors 300
#   --keep-axes; refit: bvae model refit-encoder runs/models/s28-z16r1000 --dataset runs/both.h5
#   -o runs/models/s28-z16r1000-VARIANT --name bvae-s28-z16r1000-VARIANT OPTIONS (each refit's settings: its row)
# Benchmark: bvae model disentanglement MODEL --materials 300 --seed S --no-pca (S = 0 and 2)
# Reconstruction: bvae model evaluate MODEL --dataset runs/both.h5 (and runs/random24.h5) [--effort 1] --json
# Rows: python reports/disentanglement/from_scratch_rows.py --study encoder-refit-fold2 -> encoder-refit-fold2.jsonl
""")

MEAN_RECON_FOLD2 = Study(
    name="mean-recon-fold2", session="s29", runs=("ft-mr0", "ft-mr1"),
    device="cpu: 2 cores (x86_64, torch 2.13.0+cpu), OMP_NUM_THREADS=1, beside each other and a CI run",
    training_title="Fine-tuning (this machine's CPU, one core each):",
    train_keys=("mean_recon_weight", "learning_rate"),
    references=(("bvae-cv3-fold2-v3", "runs/models/cpu21-cv3-fold2-v3"),
                ("bvae-s28-z16r1000", "runs/models/s28-z16r1000"),
                ("bvae-s28-z16r1000-refit-fw", "runs/models/s28-z16r1000-refit-fw"),
                ("bvae-s29-ft-mr1-refit", "runs/models/s29-ft-mr1-refit")),
    imported=(("reports/disentanglement/encoder-refit-fold2.jsonl",
               ("bvae-cv3-fold2-v3", "bvae-s28-z16r1000", "bvae-s28-z16r1000-refit-fw")),),
    fold=True, prefix="bvae-s29-",
    header="""\
# Issue 50, "held-out reconstruction no worse than today's model's, as in bvae model evaluate" (effort 0): no
# refit of the editing recipe's encoder alone closes its gap to the v3 recipe on MERL and analytic materials
# (encoder-refit-fold2.txt). Here the whole model is trained on: bvae train --mean-recon-weight W adds W times a
# second reconstruction term, the decoder's output at μ itself (no sampled noise), for the real and the analytic
# materials of each step, so that the codes the encoder gives are codes the decoder is trained on. Both runs
# fine-tune the recipe's fold-2 model (bvae-s28-z16r1000, --init) for 60 epochs at learning rate 1e-4 with the
# recipe's every other setting: -ft-mr1 with W = 1, -ft-mr0 with W = 0 (the control: the same fine-tuning without
# the term). Then -ft-mr1's encoder refitted to its decoder with the defaults (bvae model refit-encoder
# runs/models/s29-ft-mr1 --dataset runs/both.h5 -o runs/models/s29-ft-mr1-refit --name bvae-s29-ft-mr1-refit).
# Fold 2 of 3 (30 MERL, 10 RGL held out; NBRDF proxies, neural fits, not measurements); analytic: 24 random
# materials none saw. The other references' rows are copied from encoder-refit-fold2.jsonl.
# Commands: runs/s29/cmd-RUN.txt (in the training rows); export: bvae model export runs/s29/RUN
#   -o runs/models/s29-RUN --name bvae-s29-RUN --dataset runs/both.h5 --basis-count 0 --align-factors 300 --keep-axes
# Benchmark: bvae model disentanglement MODEL --materials 300 --seed 0 --no-pca
# Reconstruction: bvae model evaluate MODEL --dataset runs/both.h5 (and runs/random24.h5) [--effort 1] --json
# Rows: python reports/disentanglement/from_scratch_rows.py --study mean-recon-fold2 -> mean-recon-fold2.jsonl
""")

MEAN_RECON_SCRATCH_FOLD2 = Study(
    name="mean-recon-scratch-fold2", session="s30", runs=("mr03", "mr1", "mr1f20k"),
    device="cpu: 2 cores (x86_64, torch 2.13.0+cpu), OMP_NUM_THREADS=1, beside each other",
    training_title="Training from scratch (this machine's CPU, one core each):",
    train_keys=("mean_recon_weight",),
    references=(("bvae-cv3-fold2-v3", "runs/models/cpu21-cv3-fold2-v3"),
                ("bvae-s28-z16r1000", "runs/models/s28-z16r1000"),
                ("bvae-s28-z16r1000-refit-fw", "runs/models/s28-z16r1000-refit-fw"),
                ("bvae-s29-ft-mr1-refit", "runs/models/s29-ft-mr1-refit"),
                ("bvae-s30-mr03-refit", "runs/models/s30-mr03-refit"),
                ("bvae-s30-mr1-refit", "runs/models/s30-mr1-refit"),
                ("bvae-s30-mr1-refit-wide", "runs/models/s30-mr1-refit-wide"),
                ("bvae-s30-mr1f20k-refit", "runs/models/s30-mr1f20k-refit")),
    imported=(("reports/disentanglement/mean-recon-fold2.jsonl",
               ("bvae-cv3-fold2-v3", "bvae-s28-z16r1000", "bvae-s28-z16r1000-refit-fw", "bvae-s29-ft-mr1-refit")),),
    fold=True, prefix="bvae-s30-",
    header="""\
# Issue 50, "held-out reconstruction no worse than today's model's, as in bvae model evaluate" (effort 0): a
# reconstruction term at μ (bvae train --mean-recon-weight W) narrowed the editing recipe's gap to the v3 recipe when
# its fold-2 model was fine-tuned with it (mean-recon-fold2.txt). Here the recipe is trained from scratch with the
# term, exactly as bvae-s28-z16r1000 was (400 epochs, every setting the same, same seed) but for W: -mr03 with
# W = 0.3, -mr1 with W = 1; bvae-s28-z16r1000 is the control (W = 0). -mr1f20k: W = 1 with the factor terms' weight
# doubled (--factor-weight 20000), to win back the disentanglement W = 1 costs. Then each encoder refitted to its
# decoder with the defaults (bvae model refit-encoder runs/models/s30-RUN --dataset runs/both.h5 -o
# runs/models/s30-RUN-refit --name bvae-s30-RUN-refit), and -mr1's also with 1,024 analytic materials
# (--analytic-materials 1024: -mr1-refit-wide; runs/s30/refit.sh mr1 wide --analytic-materials 1024).
# Fold 2 of 3 (30 MERL, 10 RGL held out; NBRDF proxies, neural fits, not measurements); analytic: 24 random
# materials none saw. The other references' rows are copied from mean-recon-fold2.jsonl.
# Commands: runs/s30/cmd-RUN.txt (in the training rows), all of it in runs/s30/scratch.sh RUN W [FACTOR_WEIGHT];
#   export: bvae model export runs/s30/RUN -o runs/models/s30-RUN --name bvae-s30-RUN --dataset runs/both.h5
#   --basis-count 0 --align-factors 300 --keep-axes
# Benchmark: bvae model disentanglement MODEL --materials 300 --seed 0 --no-pca
# Reconstruction: bvae model evaluate MODEL --dataset runs/both.h5 (and runs/random24.h5) [--effort 1] --json
# Rows: python reports/disentanglement/from_scratch_rows.py --study mean-recon-scratch-fold2
#   -> mean-recon-scratch-fold2.jsonl
""")

FACTOR_WEIGHT_SCRATCH_FOLD2 = Study(
    name="factor-weight-scratch-fold2", session="s31", runs=("mr1f14k",),
    device="cpu: 2 cores (x86_64, torch 2.13.0+cpu), OMP_NUM_THREADS=1, beside other jobs",
    training_title="Training from scratch (this machine's CPU, one core):",
    train_keys=("mean_recon_weight",),
    references=(("bvae-cv3-fold2-v3", "runs/models/cpu21-cv3-fold2-v3"),
                ("bvae-s28-z16r1000-refit-fw", "runs/models/s28-z16r1000-refit-fw"),
                ("bvae-s30-mr1-refit", "runs/models/s30-mr1-refit"),
                ("bvae-s30-mr1f20k-refit", "runs/models/s30-mr1f20k-refit"),
                ("bvae-s31-mr1f14k-refit", "runs/models/s31-mr1f14k-refit")),
    imported=(("reports/disentanglement/mean-recon-scratch-fold2.jsonl",
               ("bvae-cv3-fold2-v3", "bvae-s28-z16r1000-refit-fw", "bvae-s30-mr1-refit", "bvae-s30-mr1f20k-refit")),),
    fold=True, prefix="bvae-s31-",
    header="""\
# Issue 50, the next step of mean-recon-scratch-fold2: the editing recipe trained from scratch with the term at μ
# weighed 1 (bvae train --mean-recon-weight 1) kept the v3 recipe's held-out errors at effort 0 but lost MIG (0.245);
# doubling the factor terms' weight (20,000) won MIG back (0.356) and lost the errors. Here the weight between:
# -mr1f14k, W = 1 and --factor-weight 14000, every other setting and the seed those runs' (400 epochs), then the
# encoder refitted with the defaults (bvae model refit-encoder runs/models/s31-mr1f14k --dataset runs/both.h5 -o
# runs/models/s31-mr1f14k-refit --name bvae-s31-mr1f14k-refit). One seed.
# Fold 2 of 3 (30 MERL, 10 RGL held out; NBRDF proxies, neural fits, not measurements); analytic: 24 random
# materials none saw. The other references' rows are copied from mean-recon-scratch-fold2.jsonl.
# Commands: runs/s31/cmd-mr1f14k.txt (in the training rows), all of it in runs/s31/scratch.sh mr1f14k 1 14000 0;
#   export: bvae model export runs/s31/mr1f14k -o runs/models/s31-mr1f14k --name bvae-s31-mr1f14k
#   --dataset runs/both.h5 --basis-count 0 --align-factors 300 --keep-axes
# Benchmark: bvae model disentanglement MODEL --materials 300 --seed 0 --no-pca
# Reconstruction: bvae model evaluate MODEL --dataset runs/both.h5 (and runs/random24.h5) [--effort 1] --json
# Rows: python reports/disentanglement/from_scratch_rows.py --study factor-weight-scratch-fold2
#   -> factor-weight-scratch-fold2.jsonl
""")

STUDIES = {study.name: study for study in (FROM_SCRATCH_SUPERVISION, FREE_DIMENSIONS, SATURATION, CPU_FOLD2,
                                           RATE_FOLD2, SWA_FOLD2, LATENT_SIZE_FOLD2, RATE_PRIOR_FOLD2,
                                           ENCODER_REFIT_FOLD2, MEAN_RECON_FOLD2, MEAN_RECON_SCRATCH_FOLD2,
                                           FACTOR_WEIGHT_SCRATCH_FOLD2)}


def text(study: Study, rows: list[dict]) -> str:
    """The study's tables, from its rows."""
    lines = [study.header, *_disentanglement_lines(rows), *_reconstruction_lines(study, rows),
             *_refinement_lines(rows), *_refit_lines(rows), *_training_lines(study, rows)]
    return "\n".join(lines) + "\n"


def _disentanglement_lines(rows: list[dict]) -> list[str]:
    """MIG and DCI per seed of the benchmark, then each dimension's dominant factor at seed 0 (nothing for a study
    that did not run the benchmark)."""
    lines = []
    scored = [row for row in rows if row.get("study") == "disentanglement"]
    if not scored:
        return []
    for seed in (0, 2):
        lines.append(f"MIG and DCI, 300 analytic materials of seed {seed} (base RelAE: the model's decode of them)")
        width = max([28, *(len(row["model"]) + 1 for row in scored)])
        lines.append(f"{'code':<{width}}{'MIG':>7}{'DCI-D':>7}{'DCI-C':>7}{'DCI-I':>7}{'base RelAE':>12}")
        lines += [f"{row['model']:<{width}}{row['mig']:7.3f}{row['dci_disentanglement']:7.3f}"
                  f"{row['dci_completeness']:7.3f}{row['dci_informativeness']:7.3f}{row['base_relae_kept_mapped']:12.4f}"
                  for row in scored if row["seed"] == seed]
        lines.append("")
    lines.append("dominant factor of each dimension, seed 0 (share of the dimension's importance):")
    for row in scored:
        if row["seed"] == 0 and row["code"] == "model":
            pairs = zip(row["dominant_factor"], row["dominant_share"], strict=True)
            dims = ", ".join(f"z{i + 1} {factor} ({share:.2f})" for i, (factor, share) in enumerate(pairs))
            lines.append(f"  {row['model']}: {dims}")
    return [*lines, ""]


def _device_analytic(row: dict) -> float | None:
    """A training row's never-seen analytic error as the device runner scored it, where it did."""
    if row.get("kind") != "training":
        return None
    return row["device_scores"]["relae"].get("analytic")


def _fold_reconstruction_lines(study: Study, rows: list[dict]) -> list[str]:
    """Each fold model's mapped RelAE per family and split, and on the never-seen analytic materials: μ of the
    encoder (effort 0), then, where measured, μ refined as ``bvae compress`` encodes (effort 1)."""
    lines = _fold_effort_lines(study, rows, 0, "Reconstruction, mapped RelAE of the encoder's μ decoded (effort 0), "
                                                "full tables, per family and split:")
    if any(row.get("kind") == "evaluation" and row.get("effort") == 1 for row in rows):
        lines += _fold_effort_lines(study, rows, 1, "The same with μ refined through the decoder as bvae compress "
                                                    "encodes (bvae model evaluate --effort 1, the codec's default):")
    return [*lines, *_grid_lines(study, rows)]


def _fold_effort_lines(study: Study, rows: list[dict], effort: int, title: str) -> list[str]:
    """One table of :func:`_fold_reconstruction_lines`: the evaluations at one encoder effort."""
    columns = {("merl", "held-out"): ("MERL", "held out"), ("rgl", "held-out"): ("RGL", "held out"),
               ("analytic", "held-out"): ("analytic", "never"), ("merl", "train"): ("MERL", "train"),
               ("rgl", "train"): ("RGL", "train")}
    counts: dict[tuple[str, str], int] = {}
    cells: dict[str, dict[tuple[str, str], float]] = {}
    for row in rows:
        if (row.get("kind") == "evaluation" and (row["family"], row["split"]) in columns and not row.get("mu_grid")
                and row.get("effort", 0) == effort):
            cells.setdefault(row["model"], {})[row["family"], row["split"]] = row["mapped"]
            counts[row["family"], row["split"]] = row["count"]
    titles = {key: f"{family} {counts.get(key, '?')} ({split})" for key, (family, split) in columns.items()}
    lines = [title, f"{'model':<33}" + "".join(f"{heading:>20}" for heading in titles.values())]
    for model in study.models:
        cell = cells.get(model, {})
        lines.append(f"{model:<33}" + "".join(f"{'—' if cell.get(key) is None else f'{cell[key]:.4f}':>20}"
                                              for key in columns))
    return [*lines, ""]


def _grid_lines(study: Study, rows: list[dict]) -> list[str]:
    """Held-out mapped RelAE of μ rounded to each grid measured (as a coded μ stores it), and μ's coded bytes under
    the format's unit prior, and where measured under per-dimension priors fitted to the training materials (with
    the fitted codes): one table per grid, coarsest first."""
    on_grid = [row for row in rows if row.get("kind") == "evaluation" and row.get("mu_grid")
               and row["split"] == "held-out"]
    families = ("merl", "rgl")
    lines = []
    for grid in sorted({row["mu_grid"] for row in on_grid}):
        cells = {(row["model"], row["family"]): row for row in on_grid if row["mu_grid"] == grid}
        fitted = any(row.get("mu_bytes_fitted") is not None for row in cells.values())
        lines += [f"μ rounded to the grid 2^-{grid} (a record's coded μ), decoded: mapped RelAE, full tables, held out "
                  "(μ's bytes coded alone under the format's unit prior"
                  + ("; then under per-dimension priors fitted to the training materials' μ" if fitted else "") + "):",
                  f"{'model':<33}{'MERL held out':>24}{'RGL held out':>24}"
                  + (f"{'MERL, fitted prior':>20}{'RGL, fitted prior':>20}" if fitted else "")]
        for model in study.models:
            line = f"{model:<33}"
            for f in families:
                cell = cells.get((model, f))
                text = "—" if cell is None else f"{cell['mapped']:.4f} ({cell['mu_bytes']:.2f} B)"
                line += f"{text:>24}"
            for f in families if fitted else ():
                value = cells.get((model, f), {}).get("mu_bytes_fitted")
                line += f"{'—' if value is None else f'{value:.2f} B':>20}"
            lines.append(line)
        lines.append("")
        if fitted:
            lines.append(f"the fitted prior codes on 2^-{grid} (the unit prior's: {16 * grid}; 16 a doubling of the "
                         "spread):")
            for model in study.models:
                codes = next((cells[model, f]["mu_prior_codes"] for f in families if (model, f) in cells), None)
                if codes is not None:
                    lines.append(f"  {model}: {' '.join(str(c) for c in codes)}")
            lines.append("")
    return lines


def _reconstruction_lines(study: Study, rows: list[dict]) -> list[str]:
    """Each model's mapped RelAE per family: trained on, never seen, and the device's own score where made."""
    if study.fold:
        return _fold_reconstruction_lines(study, rows)
    columns = {"merl": ("MERL 90 (train)", 16), "rgl": ("RGL 30 (train)", 16),
               "analytic-never": ("analytic 24 (never)", 21), "rgl-never": ("real RGL 1 (never)", 20)}
    if any(_device_analytic(row) is not None for row in rows):  # the runner scored never-seen ones
        columns["analytic-device"] = ("analytic 24 (device)", 22)
    lines = ["Reconstruction, mapped RelAE of the encoder's μ decoded (effort 0), full tables:",
             f"{'model':<28}" + "".join(f"{title:>{width}}" for title, width in columns.values())]
    for model in study.models:
        cell = {}
        for row in rows:
            if row.get("model") != model:
                continue
            if row.get("kind") == "reconstruction":
                cell[row["family"]] = row["relae_mapped"]
            if row.get("kind") == "evaluation" and row["split"] == "held-out":
                cell[f"{row['family']}-never"] = row["mapped"]
            scored = _device_analytic(row)
            if scored is not None:
                cell["analytic-device"] = scored
        lines.append(f"{model:<28}" + "".join(f"{'—' if cell.get(key) is None else f'{cell[key]:.4f}':>{width}}"
                                              for key, (_, width) in columns.items()))
    return [*lines, ""]


def _refinement_lines(rows: list[dict]) -> list[str]:
    """Mapped RelAE per encoder effort, where the study measured it."""
    refinement = [row for row in rows if row.get("kind") == "refinement"]
    if not refinement:
        return []
    lines = ["Latent refinement (BrdfEncoder effort), every 4th of the 120 materials, mapped RelAE:"]
    for row in refinement:
        per = ", ".join(f"{k} {v:.4f}" for k, v in sorted(row["relae_mapped"].items()))
        lines.append(f"  {row['model']:<28} effort {row['effort']}: all {row['all']:.4f} ({per})")
    return [*lines, ""]


def refit_rows(study: Study) -> list[dict]:
    """The refit of each refitted model of a study (``info.encoder_refit`` of its ``model.json``), and the training
    error of the models of :attr:`Study.refit_references`."""
    with BrdfDataset("runs/both.h5") as dataset:
        family = dict(zip(dataset.names, dataset.families, strict=True))
    rows = [row for name, folder in study.refit_references for row in training_error_rows(name, folder, family)]
    for name, folder in {**study.models, **dict(study.refit_references)}.items():
        manifest = Path(folder, "model.json")
        refit = json.loads(manifest.read_text())["info"].get("encoder_refit") if manifest.exists() else None
        if refit:
            rows.append({"kind": "refit", "model": name, "command": refit["command"], "config": refit["config"],
                         "seconds": refit["seconds"], "epoch_losses": refit["epoch_losses"],
                         "original_encoder_sha256": refit["original_encoder_sha256"]})
    return rows


def _refit_lines(rows: list[dict]) -> list[str]:
    """Each encoder refit's settings, time and training loss (mean mapped L1 per valid entry, augmented)."""
    refits = [row for row in rows if row.get("kind") == "refit"]
    if not refits:
        return []
    lines = ["Encoder refits (bvae model refit-encoder; loss: mean mapped L1 per valid entry of the augmented "
             "training materials):"]
    for row in refits:
        config, losses = row["config"], row["epoch_losses"]
        lines.append(f"  {row['model']}: {config['epochs']} epochs, learning rate {config['learning_rate']:g}, "
                     f"{config['analytic_materials']} analytic materials ({config['analytic_batch']} a step, factor "
                     f"weight {config['factor_weight']:g}"
                     + (f", dimensions beyond the factors at {config['free_dimension_weight']:g} of it"
                        if config.get("free_dimension_weight", 1.0) != 1.0 else "")
                     + "), colour permutations "
                     f"{'on' if config['colour_permutations'] else 'off'}, blend chance {config['mix_probability']:g}, "
                     f"in {row['seconds']:.0f} s; loss "
                     f"{losses[0]:.5f} (first epoch) to {losses[-1]:.5f} (last); from encoder "
                     f"{row['original_encoder_sha256'][:12]}")
    trained = [row for row in rows if row.get("kind") == "reconstruction"]
    if trained:
        lines += ["", "Models trained on all 120 materials, the encoder's μ decoded (the export's error, mapped RelAE, "
                  "trained materials):"]
        for model in dict.fromkeys(row["model"] for row in trained):
            cells = ", ".join(f"{row['family']} {row['relae_mapped']:.4f} ({row['count']})" for row in trained
                              if row["model"] == model)
            lines.append(f"  {model}: {cells}")
    return [*lines, ""]


def imported_rows(study: Study) -> list[dict]:
    """Rows of the models an earlier study measured (:attr:`Study.imported`), as that study committed them: the
    benchmark's and the evaluations with μ as the encoder gives it or refined (not on a coded grid)."""
    return [row for path, models in study.imported for row in read_rows(path)
            if row.get("model") in models
            and ((row.get("kind") == "evaluation" and not row.get("mu_grid")) or row.get("study") == "disentanglement")]


def _training_lines(study: Study, rows: list[dict]) -> list[str]:
    """Each run's schedule, stop and last epoch's losses."""
    lines = [study.training_title]
    for row in rows:
        if row.get("kind") == "training":
            last = row["last_epoch"]
            extra = "".join(f", {key.replace('_', ' ')} {row[key]}" for key in study.train_keys)
            if "latent_dim" in row:
                extra += f", latent {row['latent_dim']}"
            rate = f", μ's rate {last['rate_bits']:.1f} bits" if last.get("rate_bits") else ""
            lines.append(f"  {row['model']:<22} factor weight {row['factor_weight']:>7g}{extra}: "
                         f"{row['epochs_done']} of {row['epochs_planned']} epochs in {row['seconds']:.0f} s "
                         f"({row['stop_reason']}; weights of epoch {row['weights_epoch']}, learning rate "
                         f"{last['lr']:.1e} at the stop); last epoch: recon {last['recon']:.0f}, KL {last['kl']:.1f}, "
                         f"factor {last['factor']:.3f}{rate}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", choices=sorted(STUDIES), default=FROM_SCRATCH_SUPERVISION.name)
    study = STUDIES[parser.parse_args().study]
    evaluations = study.folder / "eval"
    order = {name: i for i, name in enumerate(study.models)}  # the study's models in its order, then the baselines
    rows = sorted((row for path in sorted(evaluations.glob("dis-seed*.jsonl")) for row in read_rows(path)),
                  key=lambda row: order.get(row.get("model"), len(order)))
    rows += imported_rows(study)
    rows += stamp(training_rows(study) + reconstruction_rows(study) + refit_rows(study), study=study.name)
    path = write_rows(f"reports/disentanglement/{study.name}.jsonl", rows)
    Path(f"reports/disentanglement/{study.name}.txt").write_text(text(study, rows), encoding="utf-8")
    print(f"wrote {path}: {len(rows)} rows, and {study.name}.txt")


if __name__ == "__main__":
    main()
