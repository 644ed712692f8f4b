"""``bvae model``: export a trained run as a model folder, list and verify models."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from brdfcodec.cli.usage import UsageError

__all__ = ["register"]


class RefitDefaults:
    """``bvae model refit-encoder``'s defaults, those of :class:`brdfcodec.training.encoder_refit.RefitConfig`
    (kept here so that building the parser imports no torch; a test checks that they agree)."""

    epochs = 60
    analytic_materials = 256
    learning_rate = 1e-4
    logvar_weight = 1e-3
    mix_probability = 0.25
    analytic_batch = 8
    free_dimension_weight = 1.0
    seed = 0


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``model`` sub-command group."""
    parser = subparsers.add_parser("model", help="export, list and verify trained models",
                                   description="Export, list and verify trained models.")
    actions = parser.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True
    export = actions.add_parser(
        "export", help="export the best weights of a run with its measurements and model card",
        description="Measure a finished run (per-material RelAE, PCA baseline, KL, traversals) and write "
        "encoder/decoder safetensors, model.json and MODEL_CARD.md.",
    )
    export.add_argument("run_dir", type=Path, help="run folder of `bvae train`")
    export.add_argument("-o", "--output", type=Path, required=True, help="model folder to write")
    export.add_argument("--name", required=True, help="model name, e.g. bvae-nbrdf-proxy-small-v1")
    export.add_argument("--dataset", type=Path, help="dataset to measure on (default: the run's)")
    export.add_argument("--command", dest="reproduce", default="",  # not args.command: the error prefix's
                        help="the command that reproduces the run, for the card")
    export.add_argument("--compare", action="append", default=[], metavar="LABEL=FOLDER",
                        help="an exported model to show beside this one in the card (repeatable)")
    export.add_argument("--basis-count", type=int, default=None, metavar="K",
                        help="vectors of the shared basis fitted on the training split "
                        "(default 75, at most the fitted materials − 1; 0: none)")
    export.add_argument("--basis-colour-permutations", action=argparse.BooleanOptionalAction, default=True,
                        help="fit the shared basis on the training materials in all 6 orders of their colour "
                        "channels (default; at most 5 × materials − 1 vectors), or as measured only")
    export.add_argument("--align-factors", type=int, default=0, metavar="N",
                        help="rotate the latent axes to follow the factors (albedo, hue, specular, roughness, "
                             "grazing, sheen, metallic) of N analytic materials, before measuring (0: keep the "
                             "trained axes, the default; 300 is the release recipe's)")
    export.add_argument("--keep-axes", action="store_true",
                        help="with --align-factors: measure how the trained axes follow the factors without "
                             "turning them (a run fine-tuned with `bvae train --init` from an aligned model, whose "
                             "axis penalty acted on those axes)")
    export.set_defaults(handler=run_export)
    fit = actions.add_parser(
        "fit-basis", help="fit a shared basis (the basis layer's) for an exported model",
        description="Fit the shared basis of the basis layer (principal components of the mapped kept slices "
        "of the materials the model trained on, as its model.json lists them, else of the dataset's training "
        "split; by default in all 6 orders of their colour channels) for a model folder that "
        "lacks one, and name it in model.json. The weights are not touched: the decoder hash, and every file "
        "made with the model, stay valid. A model that has a basis keeps it unless --extend or --replace is given: "
        "--extend adds vectors after the basis' own, which stay bit for bit, and names the old basis in "
        "model.json's basis_prefixes, so files made with it keep decoding; --replace fits a new basis that "
        "replaces it (a model ships one basis), and files with basis layers made with the old one no longer "
        "decode with this folder.",
    )
    fit.add_argument("folder", type=Path, help="model folder")
    fit.add_argument("--dataset", type=Path, required=True, help="dataset holding the materials the model trained on")
    fit.add_argument("--count", type=int, default=None, metavar="K", help="vectors (default 75)")
    how = fit.add_mutually_exclusive_group()
    how.add_argument("--extend", action="store_true",
                     help="grow the model's basis to K vectors, keeping its vectors bit for bit: files made with "
                     "the old basis keep decoding with this folder; the new vectors' factors are stored in 8 bits "
                     "with a scale per kept slice (spec/model.md §5), half the bytes of binary16")
    how.add_argument("--replace", action="store_true",
                     help="give a model that has a basis a new one; files with basis layers made with the old "
                     "one no longer decode with this folder")
    fit.add_argument("--colour-permutations", action=argparse.BooleanOptionalAction, default=True,
                     help="fit on the training materials in all 6 orders of their colour channels (default)")
    fit.set_defaults(handler=run_fit_basis)
    compact = actions.add_parser(
        "compact-encoder", help="store an exported model's encoder compactly (float16, basis from the decoder)",
        description="Rewrite encoder.safetensors with its large matrices in float16 and without the linear "
        "path (rebuilt from the decoder's basis when loaded); the decoder and its hash are untouched.",
    )
    compact.add_argument("folder", type=Path, help="model folder")
    compact.set_defaults(handler=run_compact_encoder)
    refit = actions.add_parser(
        "refit-encoder", help="train an exported model's encoder to its frozen decoder (better codes at effort 0)",
        description="Train the encoder alone, the decoder frozen, so that the decoded code of each material "
        "reconstructs it as well as the decoder allows (the masked mapped L1 error that refinement lowers at "
        "effort 1 and above), on the materials the model trained on (model.json's info.data.train; colour-permuted "
        "and blended) and on analytic materials drawn for the refit. The decoder, its hash and every file made "
        "with the model are unchanged; the measurements that depend on the encoder are made again and stored with "
        "the refit's settings in model.json (info.encoder_refit) and the card.",
    )
    refit.add_argument("folder", type=Path, help="model folder (rewritten in place unless -o is given)")
    refit.add_argument("--dataset", type=Path, required=True,
                       help="dataset holding every material the model trained on (bvae dataset build)")
    refit.add_argument("-o", "--output", type=Path, help="write the refitted model to this new folder instead")
    refit.add_argument("--name", help="a new name for the refitted model (default: its name)")
    refit.add_argument("--epochs", type=int, default=RefitDefaults.epochs,
                       help=f"passes over the training materials (default {RefitDefaults.epochs})")
    refit.add_argument("--analytic-materials", type=int, default=RefitDefaults.analytic_materials, metavar="N",
                       help=f"analytic materials drawn for the refit (default "
                       f"{RefitDefaults.analytic_materials}; 0: the training materials alone)")
    refit.add_argument("--analytic-batch", type=int, default=RefitDefaults.analytic_batch, metavar="N",
                       help=f"analytic materials in each step's batch (default {RefitDefaults.analytic_batch})")
    refit.add_argument("--mix-probability", type=float, default=RefitDefaults.mix_probability,
                       help=f"chance that a training material is blended with another, in reflectance (default "
                       f"{RefitDefaults.mix_probability:g})")
    refit.add_argument("--colour-permutations", action=argparse.BooleanOptionalAction, default=True,
                       help="permute each training material's colour channels at random (default)")
    refit.add_argument("--learning-rate", type=float, default=RefitDefaults.learning_rate,
                       help=f"Adam's step size (default {RefitDefaults.learning_rate:g})")
    refit.add_argument("--logvar-weight", type=float, default=RefitDefaults.logvar_weight,
                       help=f"weight of the squared change of the encoder's log σ² against the mean mapped L1 per "
                       f"valid entry (default {RefitDefaults.logvar_weight:g}: σ kept, μ free)")
    refit.add_argument("--factor-weight", type=float, metavar="W",
                       help="weight of the factor supervision of the analytic materials' μ, in training's units "
                       "(default: the model's own training weight, info.train_config.factor_weight, 0 for a model "
                       "trained without; 0: the analytic materials are left to the reconstruction)")
    refit.add_argument("--free-dimension-weight", type=float, default=RefitDefaults.free_dimension_weight,
                       metavar="F", help="factor in [0, 1] on the factor term's dimensions beyond the analytic "
                       "factors, where training holds analytic materials at 0 (default "
                       f"{RefitDefaults.free_dimension_weight:g}; 0 frees them for reconstruction; needs a factor "
                       "weight > 0)")
    refit.add_argument("--seed", type=int, default=RefitDefaults.seed, help="seed of the draws (default 0)")
    refit.add_argument("--log", type=Path, help="append a JSON line per epoch to this file")
    refit.set_defaults(handler=run_refit_encoder)
    evaluate = actions.add_parser(
        "evaluate", help="measure a model per measurement family against PCA-8/16 (RelAE, ΔE ITP)",
        description="Encode and decode every material of a dataset with a model and report, per family and "
        "split (trained on / held out), mapped and linear RelAE and ΔE ITP, beside PCA-8 and PCA-16 fitted on "
        "the model's own training materials.",
    )
    evaluate.add_argument("folder", type=Path, nargs="?", help="model folder (default: the shipped default model)")
    evaluate.add_argument("--dataset", type=Path, required=True, help="dataset (bvae dataset build), any families")
    evaluate.add_argument("--effort", type=int, choices=(0, 1, 2, 3), default=0, help="refinement effort (default 0)")
    evaluate.add_argument("--mu-grid", type=int, choices=range(1, 6), metavar="G",
                          help="decode mu rounded to the grid 2^-G (1 to 5), as a record's coded mu stores it, and "
                          "add the bytes of that mu coded alone, under the format's unit prior and under "
                          "per-dimension priors fitted to the model's training materials in the dataset, columns of "
                          "--json's rows (default: mu as the encoder gives it)")
    evaluate.add_argument("--json", action="store_true", help="print the rows as JSON")
    evaluate.add_argument("--store", action="store_true",
                          help="also store the rows in model.json and the model card (weights untouched)")
    evaluate.set_defaults(handler=run_evaluate)
    show = actions.add_parser("info", help="show a model folder's manifest, verifying its weights",
                              description="Show a model (the default one without FOLDER) and verify its hashes.")
    show.add_argument("folder", type=Path, nargs="?", help="model folder (default: the shipped default model)")
    show.set_defaults(handler=run_info)
    reg = actions.add_parser("register", help="make a model folder findable by its decoder hash from now on",
                             description="Verify a model folder and add it to the user's list of model folders, "
                             "so that .bvae files made with it decode in any later session.")
    reg.add_argument("folder", type=Path, help="model folder (written by bvae model export)")
    reg.set_defaults(handler=run_register)
    listing = actions.add_parser("list", help="list every model that can be found, in search order",
                                 description="List every findable model: name, decoder SHA-256, folder.")
    listing.set_defaults(handler=run_list)
    plaus = actions.add_parser(
        "plausibility", help="count implausible decodes over ±3σ traversals of a library",
        description="Traverse every material of a library along every latent dimension (−3…+3 prior σ) and "
        "report, per dimension and step, the fraction of decodes with non-finite or negative values, a new "
        "inverted specular peak, energy above the library's, or new zeros at the peak (brdfcodec.edit.plausibility).",
    )
    plaus.add_argument("model", nargs="?", help="model folder, model name (editing: the opt-in editing model) or "
                       "decoder SHA-256 (default: the shipped default model)")
    plaus.add_argument("--library", type=Path,
                       help=".bvae library encoded with MODEL (default: the shipped example library, 90 materials "
                       "of the NBRDF proxy of MERL, encoded with the default model: another model needs a library "
                       "of its own, e.g. bvae compress ... --model MODEL)")
    plaus.add_argument("--dims", help="latent dimensions to traverse, 1-based, comma-separated (default: all)")
    plaus.add_argument("--materials", type=int, metavar="N", help="only the first N materials of the library")
    plaus.add_argument("--tolerance", type=float, default=0.1,
                       help="inversion tolerance τ, mapped units (default 0.1)")
    plaus.add_argument("--energy-margin", type=float, default=0.1,
                       help="relative margin over the library's largest albedo (default 0.1)")
    plaus.add_argument("--raw", action="store_true",
                       help="judge the network's raw decodes, without the energy bound that edits decode with")
    plaus.add_argument("--highlight-guard", action="store_true",
                       help="also apply the highlight guard that edited records decode with since format 2.5 "
                       "(spec/bvae-format.md §6 step 6), before the energy bound: the decodes exactly as "
                       "`bvae edit` writes them (default: the network's decodes, what a training objective fixes)")
    plaus.add_argument("--json", action="store_true", help="print one JSON object")
    plaus.set_defaults(handler=run_plausibility)
    sig = actions.add_parser(
        "sigma", help="whether the posterior width σ follows the encoding error (per material and group)",
        description="Encode every material of a dataset, decode at μ, and compare the posterior width σ with the "
        "error (mapped L1 per valid entry): per material, per family and stored split, and the Spearman rank "
        "correlation with a permutation p-value (brdfcodec.report.posterior).",
    )
    sig.add_argument("dataset", type=Path, help="HDF5 dataset (bvae dataset build)")
    sig.add_argument("--model", help="model folder, model name (editing: the opt-in editing model) or decoder "
                     "SHA-256 (default: the shipped default model)")
    sig.add_argument("-o", "--output", type=Path, metavar="ROWS.jsonl",
                     help="also write the rows (brdfcodec.report.rows, study 'posterior-width')")
    sig.add_argument("--force", action="store_true", help="replace an existing output file")
    sig.set_defaults(handler=run_sigma)
    dis = actions.add_parser(
        "disentanglement", help="MIG and DCI of models' codes (and PCA-8) on materials with known factors",
        description="Draw analytic materials whose factors (albedo level and hue, specular level, roughness, "
        "grazing Fresnel, sheen, metalness) are sampled independently, encode them (the encoder's mean), and "
        "score each code with MIG and DCI disentanglement / completeness / informativeness "
        "(brdfcodec.report.disentanglement), beside PCA-8 of the same materials. Prints a table and, per "
        "latent dimension, the factor it moves most.",
    )
    dis.add_argument("models", nargs="*", metavar="MODEL",
                     help="model folders, model names or decoder SHA-256s (default: the shipped default model)")
    dis.add_argument("--materials", type=int, default=300, metavar="N",
                     help="analytic materials to draw (default 300; at least 30)")
    dis.add_argument("--seed", type=int, default=0, help="seed of the factor sampler (default 0)")
    dis.add_argument("--no-pca", action="store_true", help="leave out the PCA-8 baseline")
    dis.add_argument("-o", "--output", type=Path, metavar="ROWS.jsonl",
                     help="also write the result rows (brdfcodec.report.rows, study 'disentanglement')")
    dis.add_argument("--force", action="store_true", help="replace an existing output file")
    dis.set_defaults(handler=run_disentanglement)


def run_export(args: argparse.Namespace) -> int:
    """Export and print the decoder hash."""
    from brdfcodec.training.export import export_run

    if args.output.exists() and any(args.output.iterdir()):
        raise FileExistsError(f"{args.output}: folder is not empty")
    command = args.reproduce or " ".join(shlex.quote(a) for a in ["bvae", *sys.argv[1:]])
    comparisons = {}
    for item in args.compare:
        label, sep, folder = item.partition("=")
        if not sep or not label or not folder:
            raise ValueError(f"--compare takes LABEL=FOLDER, got {item!r}")
        comparisons[label] = Path(folder)
    from brdfcodec.training.export import DEFAULT_BASIS_COUNT

    count = DEFAULT_BASIS_COUNT if args.basis_count is None else args.basis_count
    if count < 0:
        raise ValueError(f"--basis-count must be ≥ 0, got {count}")
    if args.align_factors < 0:
        raise ValueError(f"--align-factors must be ≥ 0, got {args.align_factors}")
    if args.keep_axes and not args.align_factors:
        raise ValueError("--keep-axes measures the axes against the factors: it needs --align-factors N")
    manifest = export_run(args.run_dir, args.output, name=args.name, dataset_path=args.dataset, command=command,
                          comparisons=comparisons, basis_count=count,
                          basis_colour_permutations=args.basis_colour_permutations,
                          align_materials=args.align_factors, turn_axes=not args.keep_axes)
    print(f"wrote {args.output}: {manifest.name}, decoder sha256 {manifest.decoder_sha256}")
    return 0


def run_fit_basis(args: argparse.Namespace) -> int:
    """Fit and write the shared basis, then print its hash."""
    from brdfcodec.models.store import load_model
    from brdfcodec.training.export import DEFAULT_BASIS_COUNT, add_shared_basis

    load_model(args.folder)  # a complete, verified model folder before anything is written into it
    count = DEFAULT_BASIS_COUNT if args.count is None else args.count
    if count < 1:
        raise ValueError(f"--count must be ≥ 1, got {count}")
    manifest = add_shared_basis(args.folder, args.dataset, count, colour_permutations=args.colour_permutations,
                                replace=args.replace, extend=args.extend)
    extends = "".join(f"; its first {n} are basis {sha}, whose files keep decoding"
                      for sha, n in manifest.basis_prefixes.items())
    print(f"wrote {args.folder}/basis.safetensors: {manifest.info['basis']['count']} vectors, "
          f"sha256 {manifest.basis_sha256}{extends}")
    return 0


def run_compact_encoder(args: argparse.Namespace) -> int:
    """Compact the encoder file, then print its size and hash."""
    from brdfcodec.models.store import compact_encoder, load_model

    _, _, manifest = load_model(args.folder, parts=("decoder",))  # verified before anything is rewritten
    if not manifest.config.linear_basis:
        raise ValueError(f"{args.folder}: compact storage needs a model with a linear basis")
    manifest = compact_encoder(args.folder)
    import json

    from brdfcodec.training.export import write_card

    write_card(args.folder, json.loads((manifest.folder / "model.json").read_text(encoding="utf-8")))
    size = (manifest.folder / "encoder.safetensors").stat().st_size
    print(f"wrote {args.folder}/encoder.safetensors: {size:,} bytes, sha256 {manifest.encoder_sha256}")
    return 0


def run_refit_encoder(args: argparse.Namespace) -> int:
    """Refit the encoder, then print where it went and its reconstruction loss before and after."""
    from brdfcodec.training.encoder_refit import RefitConfig, refit_model_folder

    factor_weight = args.factor_weight
    if factor_weight is None:
        from brdfcodec.models.store import load_manifest

        trained_with = load_manifest(args.folder).info.get("train_config")
        factor_weight = float(trained_with.get("factor_weight") or 0.0) if isinstance(trained_with, dict) else 0.0
    config = RefitConfig(epochs=args.epochs, factor_weight=factor_weight, analytic_materials=args.analytic_materials,
                         learning_rate=args.learning_rate, logvar_weight=args.logvar_weight, seed=args.seed,
                         mix_probability=args.mix_probability, colour_permutations=args.colour_permutations,
                         analytic_batch=args.analytic_batch, free_dimension_weight=args.free_dimension_weight)
    command = " ".join(shlex.quote(a) for a in ["bvae", *sys.argv[1:]])
    manifest = refit_model_folder(args.folder, args.dataset, config, output=args.output, name=args.name,
                                  command=command,
                                  log=args.log)
    losses = manifest.info["encoder_refit"]["epoch_losses"]
    print(f"wrote {manifest.folder}/encoder.safetensors: sha256 {manifest.encoder_sha256}; decoder unchanged "
          f"({manifest.decoder_sha256}); training loss per valid entry {losses[0]:.5f} (first epoch) to "
          f"{losses[-1]:.5f} (last)")
    return 0


def run_evaluate(args: argparse.Namespace) -> int:
    """Print (and optionally store) the per-family table."""
    import json

    from brdfcodec.models.registry import resolve_manifest
    from brdfcodec.training.family_report import evaluate_by_family, family_table

    if args.store and args.mu_grid is not None:
        raise UsageError("--store keeps the card's table of mu as the encoder gives it: leave out --mu-grid")
    folder = resolve_manifest(args.folder).folder  # a folder, a hash or a name: --store writes where the model is
    rows = evaluate_by_family(folder, args.dataset, effort=args.effort, mu_grid=args.mu_grid)
    if args.json:
        print(json.dumps([row.as_dict() for row in rows], indent=1))
    else:
        print("\n".join(family_table(rows)))
    if args.store:
        from brdfcodec.datasets.hdf5 import BrdfDataset
        from brdfcodec.training.export import store_info

        with BrdfDataset(args.dataset) as dataset:
            description = dataset.description
        command = " ".join(shlex.quote(a) for a in ["bvae", *sys.argv[1:]])
        store_info(folder, "by_family", {"dataset": description, "effort": args.effort, "command": command,
                                         "rows": [row.as_dict() for row in rows]})
        print(f"stored in {folder}/model.json and MODEL_CARD.md")
    return 0


def run_info(args: argparse.Namespace) -> int:
    """Print name, hashes, size and headline errors after verifying the weights."""
    from brdfcodec.models.registry import default_model_folder
    from brdfcodec.models.store import load_model

    folder = args.folder or default_model_folder()
    _, _, manifest = load_model(folder)
    print(f"{manifest.folder}\n  name            {manifest.name}"
          f"\n  decoder sha256  {manifest.decoder_sha256} (verified)"
          f"\n  encoder sha256  {manifest.encoder_sha256} (verified)\n  latent size     {manifest.config.latent_dim}")
    for split, row in manifest.info.get("summary", {}).items():
        print(f"  {split:<15} mapped RelAE mean {row['mapped_mean']:.4f} (worst {row['mapped_max']:.4f}), "
              f"linear {row['linear_mean']:.4f}")
    return 0


def run_register(args: argparse.Namespace) -> int:
    """Verify the weights, then save the folder in the user's configuration."""
    from brdfcodec.models.registry import config_file, save_model_folder
    from brdfcodec.models.store import load_model

    load_model(args.folder)  # verifies both hashes before anything is saved
    manifest = save_model_folder(args.folder)
    print(f"registered {manifest.name} (decoder sha256 {manifest.decoder_sha256}) in {config_file()}")
    return 0


def run_list(args: argparse.Namespace) -> int:
    """One line per findable model."""
    from brdfcodec.models.registry import available_models

    for manifest in available_models():
        print(f"{manifest.decoder_sha256}  {manifest.name:<36} {manifest.folder}")
    return 0


def _parse_dims(text: str | None, latent_dim: int) -> list[int] | None:
    """``"1,3"`` → ``[0, 2]``; None for all."""
    if text is None:
        return None
    try:
        dims = [int(item) - 1 for item in text.split(",") if item.strip()]
    except ValueError:
        raise UsageError(f"--dims takes comma-separated integers, got {text!r}") from None
    if not dims or any(not 0 <= d < latent_dim for d in dims):
        raise UsageError(f"--dims must name dimensions in 1…{latent_dim}, got {text!r}")
    return dims


def run_plausibility(args: argparse.Namespace) -> int:
    """Measure and print the plausibility table (or JSON)."""
    from brdfcodec.codec import BrdfDecoder, MaterialLibrary
    from brdfcodec.edit.plausibility import PlausibilityCriteria, measure_plausibility
    from brdfcodec.examples import example_library

    criteria = PlausibilityCriteria(args.tolerance, args.energy_margin)
    if args.materials is not None and args.materials < 1:
        raise UsageError(f"--materials must be at least 1, got {args.materials}")
    decoder = BrdfDecoder(args.model)
    library_path = args.library or example_library()
    library_label = str(args.library) if args.library else "the shipped example library (NBRDF proxy of MERL)"
    with MaterialLibrary(library_path, decoder=decoder) as library:
        everything = [library.record(name) for name in library.names]
    records = everything[: args.materials]
    report = measure_plausibility(decoder, records, dims=_parse_dims(args.dims, decoder.latent_dim),
                                  criteria=criteria, reference=everything, energy_bound=not args.raw,
                                  highlight_guard=args.highlight_guard)
    if args.json:
        from brdfcodec.report.rows import current_commit

        summary = {"commit": current_commit(), "model": decoder.manifest.name if decoder.manifest else None,
                   "decoder_sha256": decoder.reference.sha256 if decoder.reference else None,
                   "library": library_label, **report.to_dict()}
        print(json.dumps(summary, allow_nan=False))
        return 0
    name = decoder.manifest.name if decoder.manifest else "in-memory decoder"
    judged = ("the network's raw decodes" if args.raw else "decodes with the energy bound") + (
        ", after the highlight guard of edited records" if args.highlight_guard else "")
    print(f"{name}: {len(records)} materials of {library_label}; {judged}")
    print(report.format_table())
    if report.worst:
        print("\nworst decodes:")
        for o in report.worst:
            where = f" at (colour, φd bin, θd bin) {o.where}" if o.where else ""
            print(f"  {o.kind:<9} {o.material} z{o.dim + 1}{o.step:+g}σ: {o.score:.4g}{where}")
    return 0


def run_sigma(args: argparse.Namespace) -> int:
    """Measure σ against the encoding error on a dataset, print the table, write the rows."""
    from brdfcodec.report.posterior import format_table, posterior_width_rows
    from brdfcodec.report.rows import stamp, write_rows

    if not args.dataset.is_file():
        raise FileNotFoundError(f"{args.dataset}: no such dataset file")
    if args.output is not None and args.output.exists() and not args.force:
        raise FileExistsError(f"{args.output}: exists; use --force to replace it")
    rows = posterior_width_rows(args.model, args.dataset)
    print(format_table(rows))
    if args.output is not None:
        model = ["--model", args.model] if args.model else []
        command = "bvae model sigma " + shlex.join([str(args.dataset), *model])
        write_rows(args.output, stamp(rows, study="posterior-width", command=command))
        print(f"wrote {args.output}: {len(rows)} rows")
    return 0


def run_disentanglement(args: argparse.Namespace) -> int:
    """Run the disentanglement benchmark, print its table, write its rows."""
    from brdfcodec.report.disentanglement import format_table, run_benchmark
    from brdfcodec.report.rows import stamp, write_rows

    if args.materials < 30:
        raise UsageError(f"--materials must be at least 30 (DCI trains on 2/3 of them), got {args.materials}")
    if args.output is not None and args.output.exists() and not args.force:
        raise FileExistsError(f"{args.output}: exists; use --force to replace it")
    models = list(args.models) or [None]
    rows = run_benchmark(models, count=args.materials, seed=args.seed, pca=not args.no_pca,
                         progress=lambda message: print(message, file=sys.stderr, flush=True))
    print(format_table(rows))
    if args.output is not None:
        command = "bvae model disentanglement " + shlex.join(
            [*args.models, "--materials", str(args.materials), "--seed", str(args.seed)]
            + (["--no-pca"] if args.no_pca else []))
        write_rows(args.output, stamp(rows, study="disentanglement", command=command))
        print(f"wrote {args.output}: {len(rows)} rows")
    return 0
