"""``bvae extract LIB.bvae --material A ... -o SCENE.bvae``: keep some materials of a library, bit for bit."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from brdfcodec.cli.outputs import require_output_type
from brdfcodec.cli.usage import UsageError
from brdfcodec.format.bvae import read_bvae, write_bvae

__all__ = ["register"]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``extract`` sub-command."""
    parser = subparsers.add_parser(
        "extract",
        help="copy chosen materials of a .bvae library into a new .bvae file (no re-encoding)",
        description="Write a .bvae file holding only the named materials of a library: their records and "
        "metadata are copied unchanged (same latents, same decoder), nothing is decoded or re-encoded.",
    )
    parser.add_argument("input", type=Path, metavar="LIB.bvae", nargs="?",
                        help="the library (with --scene: default, the one .bvae file the scene names)")
    parser.add_argument("--material", action="append", help="material to keep (repeatable)")
    parser.add_argument("--scene", type=Path, metavar="SCENE",
                        help="keep the materials this Mitsuba scene (.xml or .json) takes from the library")
    parser.add_argument("-o", "--output", type=Path, required=True, help="output .bvae file")
    parser.add_argument("--force", action="store_true", help="replace an existing output file")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Copy the chosen records in the order given."""
    if args.scene is not None:
        from brdfcodec.render.mitsuba_scene import scene_selection

        args.input, args.material = scene_selection(args.scene, args.input, args.material)
    if args.input is None or not args.material:
        print("bvae extract: error: name the library and at least one --material, or a --scene", file=sys.stderr)
        return 2  # a usage error, as argparse's own
    require_output_type(args.output, "extract", "compressed materials", (".bvae",))
    if args.output.resolve() == args.input.resolve():
        raise UsageError(f"{args.output}: the output must not be the input")
    library = read_bvae(args.input)
    if len(set(args.material)) != len(args.material):
        raise UsageError("a material is named twice")
    records = [library.record(name) for name in args.material]
    size = write_bvae(
        args.output, records, library.header.decoder, latent_dtype=library.header.latent_dtype, overwrite=args.force
    )
    print(f"wrote {args.output}: {len(records)} of {len(library.records)} materials, {size:,} bytes")
    return 0
