"""``bvae model``: export a trained run as a model folder, list and verify models."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from brdfcodec.cli.usage import UsageError

__all__ = ["register"]


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
    export.add_argument("--command", default="", help="the command that reproduces the run, for the card")
    export.add_argument("--compare", action="append", default=[], metavar="LABEL=FOLDER",
                        help="an exported model to show beside this one in the card (repeatable)")
    export.set_defaults(handler=run_export)
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
        "inverted specular peak, energy above the library's, or new zeros at the peak (brdfcodec.plausibility).",
    )
    plaus.add_argument("model", nargs="?", help="model folder or decoder SHA-256 (default: the shipped default model)")
    plaus.add_argument("--library", type=Path,
                       help=".bvae library encoded with MODEL (default: the shipped example library, 90 materials "
                       "of the NBRDF proxy of MERL, encoded with the default model)")
    plaus.add_argument("--dims", help="latent dimensions to traverse, 1-based, comma-separated (default: all)")
    plaus.add_argument("--materials", type=int, metavar="N", help="only the first N materials of the library")
    plaus.add_argument("--tolerance", type=float, default=0.1,
                       help="inversion tolerance τ, mapped units (default 0.1)")
    plaus.add_argument("--energy-margin", type=float, default=0.1,
                       help="relative margin over the library's largest albedo (default 0.1)")
    plaus.add_argument("--json", action="store_true", help="print one JSON object")
    plaus.set_defaults(handler=run_plausibility)


def run_export(args: argparse.Namespace) -> int:
    """Export and print the decoder hash."""
    from brdfcodec.training.export import export_run

    if args.output.exists() and any(args.output.iterdir()):
        raise FileExistsError(f"{args.output}: folder is not empty")
    command = args.command or " ".join(shlex.quote(a) for a in ["bvae", *sys.argv[1:]])
    comparisons = {}
    for item in args.compare:
        label, sep, folder = item.partition("=")
        if not sep or not label or not folder:
            raise ValueError(f"--compare takes LABEL=FOLDER, got {item!r}")
        comparisons[label] = Path(folder)
    manifest = export_run(args.run_dir, args.output, name=args.name, dataset_path=args.dataset, command=command,
                          comparisons=comparisons)
    print(f"wrote {args.output}: {manifest.name}, decoder sha256 {manifest.decoder_sha256}")
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
    from brdfcodec.examples import example_library
    from brdfcodec.plausibility import PlausibilityCriteria, measure_plausibility

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
                                  criteria=criteria, reference=everything)
    if args.json:
        summary = {"model": decoder.manifest.name if decoder.manifest else None,
                   "decoder_sha256": decoder.reference.sha256 if decoder.reference else None,
                   "library": library_label, **report.to_dict()}
        print(json.dumps(summary, allow_nan=False))
        return 0
    name = decoder.manifest.name if decoder.manifest else "in-memory decoder"
    print(f"{name}: {len(records)} materials of {library_label}")
    print(report.format_table())
    if report.worst:
        print("\nworst decodes:")
        for o in report.worst:
            where = f" at (colour, φd bin, θd bin) {o.where}" if o.where else ""
            print(f"  {o.kind:<9} {o.material} z{o.dim + 1}{o.step:+g}σ: {o.score:.4g}{where}")
    return 0
