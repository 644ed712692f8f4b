"""``bvae analytic``: write an analytic (Lambert + GGX) BRDF as a MERL file."""

from __future__ import annotations

import argparse
from pathlib import Path

from brdfcodec.cli.outputs import require_output_type
from brdfcodec.cli.usage import UsageError
from brdfcodec.datasets.analytic import ANALYTIC_PRESETS, AnalyticBRDF
from brdfcodec.io.merl import write_merl

__all__ = ["register"]


def _rgb(text: str) -> tuple[float, float, float]:
    parts = [float(p) for p in text.split(",")]
    if len(parts) == 1:
        parts *= 3
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected one number or three comma-separated numbers, got {text!r}")
    return (parts[0], parts[1], parts[2])


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``analytic`` sub-command."""
    parser = subparsers.add_parser(
        "analytic",
        help="write an analytic Lambert + GGX BRDF as a MERL .binary file",
        description="Tabulate an analytic Lambert + GGX BRDF on the MERL grid and write it as a "
        "MERL .binary file (below-horizon entries unmeasured). Pick a preset or give parameters.",
    )
    parser.add_argument(
        "preset", nargs="?", choices=sorted(ANALYTIC_PRESETS), metavar="PRESET",
        help=f"one of: {', '.join(sorted(ANALYTIC_PRESETS))}",
    )
    parser.add_argument("-o", "--output", type=Path, help="output MERL .binary file (the only type it writes)")
    parser.add_argument("--diffuse", type=_rgb, help="Lambert albedo, R,G,B in [0, 1] (custom material)")
    parser.add_argument("--specular", type=_rgb, help="Fresnel F0, R,G,B in [0, 1] (custom material)")
    parser.add_argument("--roughness", type=float, help="GGX alpha in [1e-4, 1] (custom material)")
    parser.add_argument("--list", action="store_true", help="list the presets and exit")
    parser.add_argument("--force", action="store_true", help="replace an existing output file")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Write the material, or list presets."""
    if args.list:
        for name, preset in sorted(ANALYTIC_PRESETS.items()):
            print(f"{name:<16} diffuse={preset.diffuse} specular={preset.specular} roughness={preset.roughness}")
        return 0
    if args.output is None:
        raise UsageError("an output file is required: -o OUT.binary")
    require_output_type(args.output, "analytic", "a MERL table", (".binary",))
    custom = {k: v for k in ("diffuse", "specular", "roughness") if (v := getattr(args, k)) is not None}
    if args.preset is None and not custom:
        raise UsageError("give a PRESET or custom --diffuse/--specular/--roughness (see --list)")
    if args.preset is not None:
        base = ANALYTIC_PRESETS[args.preset]
        material = AnalyticBRDF(
            args.preset if not custom else f"{args.preset}-custom",
            custom.get("diffuse", base.diffuse),
            custom.get("specular", base.specular),
            custom.get("roughness", base.roughness),
        )
    else:
        material = AnalyticBRDF(args.output.stem, **custom)
    write_merl(args.output, material.to_merl(), overwrite=args.force)
    print(f"wrote {args.output} ({material.name}: diffuse={material.diffuse}, "
          f"specular={material.specular}, roughness={material.roughness})")
    return 0
