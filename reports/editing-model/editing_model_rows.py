"""The opt-in editing model ``bvae-nbrdf-proxy-edit-v1`` (issue 50): its measurements beside the shipped default.

usage (repository root; the training in runs/s27/edit-release, its export with its encoder refitted in
runs/models/s28-edit-v1-refit, the measurements of reports/editing-model/measure.sh in runs/s28/release-eval):

    python reports/editing-model/editing_model_rows.py [--card FOLDER]

Writes ``reports/editing-model/editing-model.jsonl`` (one rows schema, ``brdfcodec.report.rows``) and
``editing-model.txt`` (the tables). With ``--card FOLDER`` it also stores the model card's sections measured after
export (``info.card_sections`` of FOLDER's ``model.json``, the card rewritten; weights untouched), from the same
rows and from the fold-2 rows of the recipe (``reports/disentanglement/rate-prior-fold2.jsonl`` and
``encoder-refit-fold2.jsonl``): every measured
number on the card comes from rows.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.report.rows import read_rows, stamp, write_rows
from brdfcodec.training.export import store_info

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "disentanglement"))
from from_scratch_rows import training_error_rows  # noqa: E402 - the studies' one reading of an export's errors

STUDY = "editing-model"
RUNS = Path("runs/s27")
#: The measurements of the model as shipped (its encoder refitted in session 28; the default model's measurements,
#: which the refit does not touch, copied from runs/s27/eval, where reports/editing-model/measure.sh wrote them).
EVALUATIONS = Path("runs/s28/release-eval")
TRAINING = RUNS / "edit-release"
#: label → folder: the editing model as shipped (exported, its encoder refitted), and the shipped default.
MODELS = {"bvae-nbrdf-proxy-edit-v1": "runs/models/s28-edit-v1-refit",
          "bvae-nbrdf-proxy-small-v3": "brdfcodec/data/models/default"}
#: The plausibility runs of reports/editing-model/measure.sh: file stem → (model label, library, highlight guard,
#: materials (the first N of the library; None: all), what the materials are).
TRAINED = "the first 40 NBRDF proxies of runs/both.h5 (both models trained on them)"
NEVER_SEEN = "24 random analytic materials (runs/random24.h5), never seen"
PLAUSIBILITY = {"plaus-edit-guard": ("bvae-nbrdf-proxy-edit-v1", "runs/s28/lib-edit.bvae", True, 40, TRAINED),
                "plaus-edit-raw": ("bvae-nbrdf-proxy-edit-v1", "runs/s28/lib-edit.bvae", False, 40, TRAINED),
                "plaus-v3-guard": ("bvae-nbrdf-proxy-small-v3", "runs/s27/lib-v3.bvae", True, 40, TRAINED),
                "plaus-v3-raw": ("bvae-nbrdf-proxy-small-v3", "runs/s27/lib-v3.bvae", False, 40, TRAINED),
                "plaus-edit-guard-analytic": ("bvae-nbrdf-proxy-edit-v1", "runs/s28/lib-edit-analytic.bvae", True, None,
                                              NEVER_SEEN),
                "plaus-v3-guard-analytic": ("bvae-nbrdf-proxy-small-v3", "runs/s27/lib-v3-analytic.bvae", True, None,
                                            NEVER_SEEN)}
#: The recipe's fold-2 models (the same options, 80 materials): the editing model's (its encoder refitted as the
#: shipped model's is, then as trained), and the default's; the rows files they are in.
REFIT_FOLD2_ROWS = Path("reports/disentanglement/encoder-refit-fold2.jsonl")
FOLD2_ROWS = Path("reports/disentanglement/rate-prior-fold2.jsonl")
FOLD2_MODELS = {"bvae-s28-z16r1000-refit-fw": "editing recipe, encoder refitted",
                "bvae-s26-z16r1000": "editing recipe, as trained", "bvae-cv3-fold2-v3": "default (v3) recipe"}
#: Which study's rows each fold-2 model's are (the refit study copies the other two's; they are read from theirs).
FOLD2_SOURCES = {"bvae-s28-z16r1000-refit-fw": REFIT_FOLD2_ROWS, "bvae-s26-z16r1000": FOLD2_ROWS,
                 "bvae-cv3-fold2-v3": FOLD2_ROWS}
SHEETS = ("gold-metallic-paint", "blue-acrylic")
FAMILY_WORDS = {"merl": "MERL", "rgl": "RGL", "analytic": "analytic materials"}
#: Issue 50's goals.
GOALS = {"mig": 0.30, "dci_disentanglement": 0.70, "inverted_wide": 0.01}

HEADER = """\
# The opt-in editing model bvae-nbrdf-proxy-edit-v1 (issue 50): the supervised 16-dimensional recipe of
# reports/disentanglement/rate-prior-fold2.txt (dimensions 1-8 tied to the analytic factors at weight 10,000, the
# colour's saturation an eighth factor, GGX alpha of the factor pool from 0.01, the codec's rate in the loss at
# lambda 1,000 on the grid 2^-2, 400 epochs, last weights) trained on all 120 NBRDF proxies (90 MERL, 30 RGL; neural
# fits, not measurements) on this machine's 2-core CPU, beside the shipped default bvae-nbrdf-proxy-small-v3; its
# encoder refitted to its frozen decoder after export (bvae model refit-encoder, session 28: decoder and files
# unchanged; reports/disentanglement/encoder-refit-fold2.txt measured the refit on the recipe's fold-2 model).
# Commands: runs/s27/cmd-edit-release.txt (in the training row, and the card's); export, refit and measurements,
#   every command: reports/editing-model/measure.sh (bvae model export ... --align-factors 300 --keep-axes; bvae model
#   refit-encoder; bvae model disentanglement on seeds 0 and 2; bvae model evaluate on runs/v3-held-out.h5 at effort
#   0 and 1; bvae model
#   plausibility of libraries compressed with each model, with and without --highlight-guard; the traversal sheets)
# Held-out materials: a release model trained on every material has none of MERL or RGL; the recipe's fold-2 models
#   (80 materials, 40 held out) are in reports/disentanglement/rate-prior-fold2.txt and encoder-refit-fold2.txt and
#   quoted below.
# Rows: python reports/editing-model/editing_model_rows.py [--card FOLDER] -> editing-model.jsonl
"""


def disentanglement_rows() -> list[dict[str, Any]]:
    """The benchmark's rows (``bvae model disentanglement -o``), seeds 0 and 2, as written (already stamped)."""
    return [row for seed in (0, 2) for row in read_rows(EVALUATIONS / f"dis-seed{seed}.jsonl")]


def plausibility_rows() -> list[dict[str, Any]]:
    """One row per plausibility run: the mean fraction of each kind over dimensions and steps, and the worst cell."""
    rows = []
    for stem, (model, library, guard, count, materials) in PLAUSIBILITY.items():
        summary = json.loads((EVALUATIONS / f"{stem}.json").read_text())
        assert summary["highlight_guard"] is guard, stem
        fractions = summary["fractions"]
        worst = {kind: max((value, dim, step) for dim, row in zip(summary["dims"], values, strict=True)
                           for step, value in zip(summary["steps"], row, strict=True))
                 for kind, values in fractions.items()}
        rows.append({
            "kind": "plausibility", "model": model, "decoder_sha256": summary["decoder_sha256"], "library": library,
            "materials": summary["materials"],
            "material_set": materials,
            "dims": len(summary["dims"]), "steps": summary["steps"], "highlight_guard": guard,
            "energy_bound": summary["energy_bound"],
            "decodes": summary["materials"] * len(summary["dims"]) * len(summary["steps"]),
            "mean_fraction": {kind: sum(map(sum, values)) / sum(map(len, values))
                              for kind, values in fractions.items()},
            "worst_dim_step": {kind: {"fraction": value, "dim": dim, "step": step}
                               for kind, (value, dim, step) in worst.items()},
            "command": f"bvae model plausibility {MODELS[model]} --library {library}"
                       f"{f' --materials {count}' if count else ''}{' --highlight-guard' if guard else ''} --json",
        })
    return rows


def reconstruction_rows() -> list[dict[str, Any]]:
    """Each model's training error per family (the export's), and its never-seen error (``bvae model evaluate``)."""
    with BrdfDataset("runs/both.h5") as dataset:
        family = dict(zip(dataset.names, dataset.families, strict=True))
    rows = []
    for label, folder in MODELS.items():
        rows += training_error_rows(label, folder, family)
        for effort in (0, 1):
            evaluated = EVALUATIONS / f"evaluate-{'e1-' if effort else ''}{Path(folder).name}.json"
            option = " --effort 1" if effort else ""
            rows += [{"kind": "evaluation", "model": label, **row, "effort": effort, "dataset": "runs/v3-held-out.h5",
                      "command": f"bvae model evaluate {folder} --dataset runs/v3-held-out.h5{option} --json"}
                     for row in json.loads(evaluated.read_text()) if row["split"] == "held-out"]
    return rows


def training_rows() -> list[dict[str, Any]]:
    """The release training's row: its command, schedule, stop and last epoch's losses (runs/s27/edit-release)."""
    log = [json.loads(line) for line in (TRAINING / "log.jsonl").read_text().splitlines() if line.strip()]
    summary = json.loads((TRAINING / "summary.json").read_text())
    described = json.loads((TRAINING / "run.json").read_text())
    config = described["train_config"]
    return [{
        "kind": "training", "model": "bvae-nbrdf-proxy-edit-v1",
        "device": "cpu: 2 cores (x86_64), one run with OMP_NUM_THREADS=2", "torch": described["torch_version"],
        "command": (RUNS / "cmd-edit-release.txt").read_text().strip(), "factor_weight": config["factor_weight"],
        "latent_dim": described["model_config"]["latent_dim"], "latent_grid": config.get("latent_grid"),
        "rate_weight": config.get("rate_weight"), "epochs_planned": config["epochs"],
        "epochs_done": summary["epochs_done"], "weights_epoch": log[-1]["epoch"], "stop_reason": summary["stop_reason"],
        "seconds": summary["seconds_this_session"],
        "last_epoch": {k: log[-1][k] for k in ("lr", "recon", "kl", "traversal", "factor", "rate_bits")
                       if k in log[-1]},
    }]


def fold2_rows() -> list[dict[str, Any]]:
    """The recipe's fold-2 rows this report quotes (held-out reconstruction at effort 0 and 1, MIG and DCI)."""
    return [row for model, path in FOLD2_SOURCES.items() for row in read_rows(path)
            if row.get("model") == model
            and (row.get("study") == "disentanglement"
                 or (row.get("kind") == "evaluation" and row.get("split") == "held-out"
                     and "--mu-grid" not in row["command"]))]


# ---- text -------------------------------------------------------------------------------------------------------

def _scores(rows: list[dict], model: str) -> dict[int, dict]:
    return {row["seed"]: row for row in rows if row.get("study") == "disentanglement" and row["model"] == model
            and row.get("code") == "model"}


def disentanglement_lines(rows: list[dict]) -> list[str]:
    """MIG and DCI-D of both models on seeds 0 and 2 (Markdown), and the editing model's dominant factors."""
    lines = ["| model | MIG, seed 0 | DCI-D, seed 0 | MIG, seed 2 | DCI-D, seed 2 | base RelAE, seed 0 |",
             "|---|---:|---:|---:|---:|---:|"]
    for label in MODELS:
        scores = _scores(rows, label)
        lines.append(f"| {label} | {scores[0]['mig']:.3f} | {scores[0]['dci_disentanglement']:.3f} | "
                     f"{scores[2]['mig']:.3f} | {scores[2]['dci_disentanglement']:.3f} | "
                     f"{scores[0]['base_relae_kept_mapped']:.4f} |")
    dominant = _scores(rows, "bvae-nbrdf-proxy-edit-v1")[0]
    pairs = zip(dominant["dominant_factor"], dominant["dominant_share"], strict=True)
    lines += ["", "Factor each dimension of the editing model moves most, seed 0 (its share of the dimension's "
              "importance): " + ", ".join(f"z{i + 1} {f} ({s:.2f})" for i, (f, s) in enumerate(pairs)) + "."]
    return lines


def plausibility_lines(rows: list[dict]) -> list[str]:
    """One Markdown row per plausibility run: mean fractions over dimensions and steps, and the worst cell."""
    lines = ["| materials | model | decodes | judged | inverted highlight (judge's window) | worst dimension and "
             "step | pits | holes | unphysical |", "|---|---|---:|---|---:|---|---:|---:|---:|"]
    for row in rows:
        if row.get("kind") != "plausibility":
            continue
        mean, worst = row["mean_fraction"], row["worst_dim_step"]["inverted_wide"]
        judged = "as edits decode (guard, energy bound)" if row["highlight_guard"] else "network (energy bound)"
        lines.append(f"| {row['material_set']} | {row['model']} | {row['decodes']:,} | {judged} | "
                     f"{100 * mean['inverted_wide']:.2f} % | "
                     + (f"z{worst['dim']} {worst['step']:+g}σ: {100 * worst['fraction']:.1f} %" if worst["fraction"]
                        else "none") + " | "
                     f"{100 * mean['pits']:.2f} % | {100 * mean['holes']:.2f} % | {100 * mean['unphysical']:.2f} % |")
    return lines


def _family_errors(rows: list[dict], model: str, effort: int) -> dict[str, float]:
    return {row["family"]: row["mapped"] for row in rows if row.get("kind") == "evaluation" and row["model"] == model
            and row["effort"] == effort}


def reconstruction_lines(rows: list[dict], fold2: list[dict]) -> list[str]:
    """Mapped RelAE tables: trained materials, never-seen materials at effort 0 and 1, the recipes' fold-2 models."""
    lines = ["Trained materials (the export's error: the encoder's μ decoded, mapped RelAE, full tables):", "",
             "| model | MERL (90) | RGL (30) |", "|---|---:|---:|"]
    for label in MODELS:
        errors = {row["family"]: row["relae_mapped"] for row in rows
                  if row.get("kind") == "reconstruction" and row["model"] == label}
        lines.append(f"| {label} | {errors['merl']:.4f} | {errors['rgl']:.4f} |")
    lines += ["", "Materials no model here saw (`runs/v3-held-out.h5`: 24 random analytic materials, 1 real RGL "
              "measurement), mapped RelAE at effort 0 (the encoder's μ) and 1 (the codec's default):", "",
              "| model | effort | analytic (24) | real RGL (1) |", "|---|---:|---:|---:|"]
    for effort in (0, 1):
        for label in MODELS:
            errors = _family_errors(rows, label, effort)
            lines.append(f"| {label} | {effort} | {errors['analytic']:.4f} | {errors['rgl']:.4f} |")
    lines += ["", "The recipe on fold 2 (80 materials trained on, the 40 others held out; "
              "`reports/disentanglement/rate-prior-fold2.txt`, `encoder-refit-fold2.txt`), held-out mapped RelAE:", "",
              "| recipe (fold-2 model) | effort | MERL (30) | RGL (10) | analytic (24, never seen) |",
              "|---|---:|---:|---:|---:|"]
    for effort in (0, 1):
        for model, recipe in FOLD2_MODELS.items():
            errors = _family_errors(fold2, model, effort)
            lines.append(f"| {recipe} (`{model}`) | {effort} | {errors['merl']:.4f} | {errors['rgl']:.4f} | "
                         f"{errors['analytic']:.4f} |")
    return lines


def refit_rows() -> list[dict[str, Any]]:
    """The shipped model's encoder refit (``info.encoder_refit`` of its ``model.json``)."""
    folder = MODELS["bvae-nbrdf-proxy-edit-v1"]
    refit = json.loads(Path(folder, "model.json").read_text())["info"]["encoder_refit"]
    return [{"kind": "refit", "model": "bvae-nbrdf-proxy-edit-v1", "command": refit["command"],
             "config": refit["config"], "seconds": refit["seconds"], "epoch_losses": refit["epoch_losses"],
             "original_encoder_sha256": refit["original_encoder_sha256"]}]


def training_lines(rows: list[dict]) -> list[str]:
    """The training row in one line, then the encoder's refit."""
    row = next(r for r in rows if r.get("kind") == "training")
    refit = next(r for r in rows if r.get("kind") == "refit")
    config, losses = refit["config"], refit["epoch_losses"]
    last = row["last_epoch"]
    return [f"{row['model']}: latent {row['latent_dim']}, factor weight {row['factor_weight']:g}, rate weight "
            f"{row['rate_weight']:g} on the grid 2^-{row['latent_grid']}: {row['epochs_done']} of "
            f"{row['epochs_planned']} epochs in {row['seconds'] / 60:.0f} min ({row['stop_reason']}; {row['device']}); "
            f"last epoch: recon {last['recon']:.0f}, KL {last['kl']:.1f}, factor {last['factor']:.3f}, μ's rate "
            f"{last.get('rate_bits', float('nan')):.1f} bits",
            f"its encoder refitted to the frozen decoder ({refit['command']}): {config['epochs']} epochs at learning "
            f"rate {config['learning_rate']:g}, {config['analytic_batch']} of {config['analytic_materials']} analytic "
            f"materials a step held on their factors at weight {config['factor_weight']:g}, in "
            f"{refit['seconds'] / 60:.1f} min; mean mapped L1 per valid entry {losses[0]:.5f} (first epoch) to "
            f"{losses[-1]:.5f} (last); it replaced encoder {refit['original_encoder_sha256'][:12]}"]


def text(rows: list[dict], fold2: list[dict]) -> str:
    """The report (editing-model.txt): the header, then every table, from the rows."""
    sections = [HEADER, "## Disentanglement (300 analytic materials per seed, `bvae model disentanglement`)", "",
                *disentanglement_lines(rows), "",
                "## Plausibility of traversals (every dimension, ±1, 2, 3σ)", "", *plausibility_lines(rows), "",
                "## Reconstruction", "", *reconstruction_lines(rows, fold2), "", "## Training", "",
                *training_lines(rows)]
    return "\n".join(sections) + "\n"


# ---- the model card's sections ------------------------------------------------------------------------------------

def _comparison_sentence(fold2: list[dict]) -> str:
    """Where the editing recipe's fold-2 model is no worse than the default recipe's, at each effort (from rows)."""
    edit, _, default = FOLD2_MODELS
    words = {0: "With the encoder's μ alone (effort 0)", 1: "At the codec's default effort (1: μ refined through the "
             "decoder, as `bvae compress` encodes)"}
    parts = []
    for effort in (1, 0):
        ours, theirs = _family_errors(fold2, edit, effort), _family_errors(fold2, default, effort)
        worse = [FAMILY_WORDS[f] for f in FAMILY_WORDS if ours[f] > theirs[f]]
        parts.append(f"{words[effort]} the editing recipe, its encoder refitted as this model's, is "
                     + ("no worse than the default's on every family" if not worse
                        else f"worse than the default's on {' and '.join(worse)}") + ".")
    return " ".join(parts)


def card_sections(rows: list[dict], fold2: list[dict], sheet_prefix: str) -> list[dict[str, str]]:
    """The sections of the editing model's card measured after export, from the rows (no measured number typed)."""
    edit, v3 = _scores(rows, "bvae-nbrdf-proxy-edit-v1"), _scores(rows, "bvae-nbrdf-proxy-small-v3")
    mu_bytes = {row["model"]: row["mu_bytes"] for model, path in FOLD2_SOURCES.items() for row in read_rows(path)
                if row.get("kind") == "evaluation" and row.get("model") == model and row["family"] == "merl"
                and row["split"] == "held-out" and row["command"].endswith("--mu-grid 2 --json")}
    purpose = (
        "An opt-in model for editing (`--model editing`; issue 50), beside the codec's default "
        "`bvae-nbrdf-proxy-small-v3`, which stays the default for compression. Its 16 latent dimensions were trained "
        "with dimensions 1–8 tied to named factors of analytic materials (albedo, hue, specular, roughness, grazing, "
        "sheen, metallic, saturation). On analytic materials the first seven follow their factors (the benchmark "
        "measures seven; saturation is not among them): MIG "
        f"{edit[0]['mig']:.3f} and DCI disentanglement {edit[0]['dci_disentanglement']:.3f} on 300 analytic materials "
        f"(the default: {v3[0]['mig']:.3f} and {v3[0]['dci_disentanglement']:.3f}, about what a rotation of PCA-8 "
        "gives). On the materials of the traversal sheets a slider's largest effect is not always its factor's "
        "(*What each dimension controls* above measures each one): the names come from analytic materials, whose "
        "factors are known. What it gives up: 16 numbers instead of 8, so its records are larger (the coded μ of a "
        f"held-out MERL material alone takes {mu_bytes['bvae-s28-z16r1000-refit-fw']:.1f} B on the grid 2^-2 where the "
        f"default's takes {mu_bytes['bvae-cv3-fold2-v3']:.1f} B, on the recipes' fold-2 models; "
        "`reports/disentanglement/encoder-refit-fold2.txt`), it fits no 16 B record (`bvae compress --bytes 16` "
        "refuses it with a latent in every record, the default), and at 32 B its recipe's fold-2 model (as trained, "
        "before a refit) decodes worse than the best PCA (`reports/results/rd-s26-fold2-z16r1000-table.md`), where "
        "the default's recipe does better "
        "(`docs/results.md`). Files made with it name its decoder, so they decode wherever this package is "
        "installed."
    )
    fold_lines = reconstruction_lines(rows, fold2)
    start = next(i for i, line in enumerate(fold_lines) if line.startswith("The recipe on fold 2"))
    sheets = "\n\n".join(f"![Traversal sheet, {name}]({sheet_prefix}editing-model-{name}.png)" for name in SHEETS)
    return [
        {"title": "What this model is for", "markdown": purpose},
        {"title": "Disentanglement",
         "markdown": "\n".join([
             "`bvae model disentanglement` on 300 analytic materials whose factors are known (seeds 0 and 2; rows and "
             "command in `reports/editing-model/editing-model.txt`): MIG and DCI disentanglement of the encoder's μ, "
             f"against issue 50's goals MIG ≥ {GOALS['mig']:.2f} and DCI-D ≥ {GOALS['dci_disentanglement']:.2f}.",
             "", *disentanglement_lines(rows),
             "", "Traversal sheets (every dimension, −3σ to +3σ, decoded as edits decode), made by "
             "`bvae render LIB --material NAME --traversal -o SHEET.png` with LIB the NBRDF proxies compressed with "
             "this model:", "", sheets])},
        {"title": "Plausibility of traversals",
         "markdown": "\n".join([
             "`bvae model plausibility` on materials compressed with each model (every dimension, ±1, 2, 3 prior σ; "
             "commands in `reports/editing-model/editing-model.txt`). *Inverted "
             "highlight*: issue 50's judge (the peak at θh < 2° darker than half the body at θh 40–60° in some "
             "column where the material's own decode is not), the report's `inverted_wide`. Edits decode with the "
             "highlight guard and the energy bound (`spec/bvae-format.md` §6 steps 5–6); the network's own decodes "
             "are shown too.", "", *plausibility_lines(rows)])},
        {"title": "Reconstruction on materials it never saw",
         "markdown": "\n".join([
             "This model trained on every material the project holds, so the recipe's held-out error comes from its "
             "fold-2 model, trained the same way on 80 of them. " + _comparison_sentence(fold2), "",
             *fold_lines[start + 2:], "", *fold_lines[:start]])},
    ]


def main() -> None:
    """Collect the rows, write the rows file and the report, and store the card's sections where asked."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--card", type=Path, help="model folder whose card sections to store (the packaged model)")
    parser.add_argument("--sheet-prefix", default="../../../../../reports/traversals/",
                        help="where the traversal sheets are, relative to the card")
    args = parser.parse_args()
    rows = disentanglement_rows() + stamp(plausibility_rows() + reconstruction_rows() + training_rows()
                                          + refit_rows(), study=STUDY)
    fold2 = fold2_rows()
    path = write_rows(f"reports/editing-model/{STUDY}.jsonl", rows)
    Path(f"reports/editing-model/{STUDY}.txt").write_text(text(rows, fold2), encoding="utf-8")
    print(f"wrote {path}: {len(rows)} rows, and {STUDY}.txt")
    if args.card:
        sections = card_sections(rows, fold2, args.sheet_prefix)
        store_info(args.card, "card_sections", sections)
        print(f"stored {len(sections)} card sections in {args.card}/model.json")


if __name__ == "__main__":
    main()
