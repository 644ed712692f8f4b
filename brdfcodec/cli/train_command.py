"""``bvae train``: train a β-VAE on a dataset file (one process, or many under torchrun)."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

__all__ = ["register"]

_PRESETS = ("small", "paper", "tiny")


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``train`` sub-command."""
    parser = subparsers.add_parser(
        "train",
        help="train a β-VAE on a dataset (CPU, GPU, or torchrun for several processes)",
        description="Train a β-VAE on the training split of a dataset built by `bvae dataset build`. "
        "Several processes or machines: `torchrun --nproc_per_node N -m brdfcodec train ...`.",
    )
    parser.add_argument("dataset", type=Path, help="dataset .h5 file (with full tables)")
    parser.add_argument("-o", "--run-dir", type=Path, required=True, help="run folder (logs, checkpoints)")
    parser.add_argument("--model", default=None,
                        help=f"model size: {', '.join(_PRESETS)} (default small), or a JSON file of ModelConfig "
                        "fields")
    parser.add_argument("--init", type=Path, dest="initial_model", metavar="MODEL_DIR",
                        help="start from the weights of this exported model folder (fine-tuning; its "
                        "configuration is the run's), e.g. one turned by `bvae model export --align-factors` so "
                        "that the axis penalty acts on its aligned axes")
    parser.add_argument("--latent-dim", type=int, help="override the latent size")
    parser.add_argument("--linear-basis", action=argparse.BooleanOptionalAction, default=None,
                        help="override the model's linear (PCA) path")
    parser.add_argument("--epochs", type=int)
    parser.add_argument("--batch-size", type=int, help="global batch")
    parser.add_argument("--lr", type=float, dest="learning_rate")
    parser.add_argument("--weight-decay", type=float,
                        help="decoupled (AdamW) decay of the weights, per unit of learning rate (0: Adam)")
    parser.add_argument("--decoder-dropout", type=float,
                        help="probability of dropping a hidden unit of the decoder's first fully connected layer")
    parser.add_argument("--traversal-weight", type=float,
                        help="weight of the traversal plausibility penalty (0: none; see TrainConfig)")
    parser.add_argument("--traversal-range", type=float,
                        help="largest traversal offset of that penalty, prior σ units (default 3)")
    parser.add_argument("--traversal-directions", choices=("axes", "any"),
                        help="directions that penalty traverses: the latent axes (default) or any unit vector "
                             "(keeps every direction plausible, also the axes of `bvae model export "
                             "--align-factors`)")
    parser.add_argument("--traversal-hole-margin", type=float,
                        help="mapped height above the floor that the penalty keeps a lit highlight's centre at "
                        "(0: only crossing the floor is penalised, the default)")
    parser.add_argument("--traversal-pit-weight", type=float,
                        help="weight of the penalty's term against a highlight that darkens towards its centre "
                        "(within 4.4° of the half vector) more than the material does (0: none, the default)")
    parser.add_argument("--linear-path-rate", type=float,
                        help="learning rate of the decoder's linear (PCA) path as a fraction of the network's "
                             "(0: frozen, the default)")
    parser.add_argument("--factor-weight", type=float,
                        help="weight of the factor supervision: each step also trains on analytic materials of "
                        "known factors and pulls latent dimension j towards factor j (albedo, hue, specular, "
                        "roughness, grazing, sheen, metallic; 0 beyond), standardised (0: none, the default)")
    parser.add_argument("--factor-batch", type=int, help="analytic materials per step of that supervision (default 8)")
    parser.add_argument("--factor-materials", type=int,
                        help="size of its pool of analytic materials, tabulated at the start (default 256)")
    parser.add_argument("--factor-seed", type=int,
                        help="seed of that pool (default 100; keep it apart from the benchmark's and the "
                        "alignment's seeds, 0 and 1)")
    parser.add_argument("--factor-saturation", action="store_true", default=None,
                        help="vary that pool's colour saturation too (grey to saturated; otherwise 0.7) and tie "
                        "latent dimension 8 to it (only with --factor-weight > 0)")
    parser.add_argument("--factor-alpha-min", type=float, metavar="ALPHA",
                        help="that pool's sharpest GGX α: its roughness factor is log-uniform from ALPHA to 0.6 "
                        "(default 0.03, the disentanglement benchmark's; only with --factor-weight > 0)")
    parser.add_argument("--latent-grid", type=int, metavar="G", choices=range(0, 6),
                        help="quantisation-aware latent: add uniform noise of width 2^-G to z in training, the "
                        "rounding of the coded mu on that grid (format 2.5, section 4.9; 1 to 5; 0: none, the "
                        "default)")
    parser.add_argument("--mean-recon-weight", type=float, metavar="W",
                        help="weight of a second reconstruction term, the decoder at mu itself (no noise), so that "
                        "the encoder's codes are ones the decoder is trained on (0: none; see TrainConfig)")
    parser.add_argument("--edge-slots", action="store_true", default=None,
                        help="train the kept slots below the horizon that the interpolation carries into valid "
                        "bins towards the values that fit those bins best (the input mask leaves them out; see "
                        "TrainConfig.edge_slots; needs full tables)")
    parser.add_argument("--rate-weight", type=float, metavar="LAMBDA",
                        help="weight of mu's code length on the grid 2^-G under the format's unit Laplace prior "
                        "(nats, against the reconstruction error summed over a material's entries), so that training "
                        "minimises D + LAMBDA*R; about 70 values a nat as the codec's basis layer does at 16-32 B "
                        "(needs --latent-grid; 0: none, the default)")
    parser.add_argument("--average-from-epoch", type=int,
                        help="average the weights of every step from this epoch on (stochastic weight averaging; "
                             "validation, best.pt and the export use the average; 0: never, the default)")
    parser.add_argument("--beta", type=float)
    parser.add_argument("--recon", choices=("l2", "l1"))
    parser.add_argument("--permute-colours", type=float, help="probability of a colour permutation")
    parser.add_argument("--mix-probability", type=float, help="probability of a reflectance blend")
    parser.add_argument("--seed", type=int)
    parser.add_argument("--eval-every", type=int)
    parser.add_argument("--patience", type=int, help="evaluations without gain before stopping (0: never)")
    parser.add_argument("--time-limit", type=float, dest="time_limit_s", help="seconds; checkpoint and stop")
    parser.add_argument("--folds", type=int, help="cross-validation: deal the materials into this many folds, "
                        "stratified by family (the stored split is ignored)")
    parser.add_argument("--fold", type=int, help="the fold held out (0 to folds - 1)")
    parser.add_argument("--train-families", help="comma-separated families to train on; every other family "
                        "is held out (a family never seen)")
    parser.add_argument("--all-materials", action="store_true", default=None,
                        help="train on every material (the stored split ignored, nothing held out; needs "
                        "--keep last): the release model, once the recipe is chosen by cross-validation")
    parser.add_argument("--keep", choices=("best", "last"),
                        help="weights to keep: best on the held-out materials (default), or the last ones "
                        "(use it when the held-out materials are the test set)")
    parser.add_argument("--resume", action="store_true", help="continue the run in --run-dir")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def _model_config(spec: str, latent_dim: int | None, linear_basis: bool | None):  # noqa: ANN202
    from brdfcodec.models.config import PAPER_CONFIG, SMALL_CONFIG, TINY_CONFIG, ModelConfig

    presets = {"small": SMALL_CONFIG, "paper": PAPER_CONFIG, "tiny": TINY_CONFIG}
    if spec in presets:
        config = presets[spec]
    else:
        path = Path(spec)
        if not path.is_file():
            raise ValueError(f"--model must be one of {', '.join(_PRESETS)} or a JSON file; {spec!r} is neither")
        config = ModelConfig.from_dict(json.loads(path.read_text()))
    if latent_dim is not None:
        config = dataclasses.replace(config, latent_dim=latent_dim)
    if linear_basis is not None:
        config = dataclasses.replace(config, linear_basis=linear_basis)
    return config


def run(args: argparse.Namespace) -> int:
    """Train, then print where the results are."""
    from brdfcodec.training.config import TrainConfig
    from brdfcodec.training.trainer import train

    overrides = {
        field.name: getattr(args, field.name)
        for field in dataclasses.fields(TrainConfig)
        if getattr(args, field.name, None) is not None
    }
    if args.initial_model is not None and args.model is None:
        from brdfcodec.models.store import load_manifest

        model_config = load_manifest(args.initial_model).config
        if args.latent_dim is not None or args.linear_basis is not None:
            raise ValueError("--latent-dim and --linear-basis cannot change the model of --init")
    else:
        model_config = _model_config(args.model or "small", args.latent_dim, args.linear_basis)
    result = train(
        args.dataset, args.run_dir, model_config=model_config, train_config=TrainConfig(**overrides),
        resume=args.resume, progress=not args.quiet, initial_model=args.initial_model,
    )
    if result.run_dir.joinpath("summary.json").exists():
        print(f"{result.run_dir}: {result.epochs_done} epochs ({result.stop_reason}), best validation mapped "
              f"RelAE {result.best_validation_relae:.4f} at epoch {result.best_epoch}, {result.seconds:.0f} s")
    return 0
