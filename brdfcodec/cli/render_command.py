"""``bvae render IN -o OUT.png|OUT.exr``: preview a material (sphere, flat sample, environment, traversal sheet)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.cli.edit_command import parse_floats
from brdfcodec.cli.outputs import require_output_type
from brdfcodec.io.atomic import check_output_path

__all__ = ["register"]


def _vector(text: str) -> tuple[float, float, float]:
    values = parse_floats(text)
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected x,y,z, got {text!r}")
    return (values[0], values[1], values[2])


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``render`` sub-command."""
    parser = subparsers.add_parser(
        "render",
        help="render a material (.bvae or MERL .binary) to PNG or EXR",
        description="Render a sphere (default) or a flat sample under a directional light, or a sphere under an "
        "environment; or, with --traversal, a sheet with one row per latent parameter. PNG is exposed and "
        "sRGB-encoded; EXR holds linear radiance.",
    )
    parser.add_argument("input", type=Path, metavar="IN", nargs="?", help=".bvae file, MERL .binary or RGL .bsdf file")
    parser.add_argument("-o", "--output", type=Path, required=True, help="output .png or .exr")
    parser.add_argument("--material", help="material of a .bvae library (default: the only one)")
    parser.add_argument("--size", type=int, default=256, help="image size in pixels (default 256)")
    parser.add_argument("--light", type=_vector, default=(-1.0, 1.0, 1.0),
                        help="direction towards the light, x,y,z (camera looks down -z; default -1,1,1)")
    parser.add_argument("--env", metavar="sky|MAP.exr",
                        help="light with an environment instead: the built-in sky or a lat-long EXR")
    parser.add_argument("--flat", action="store_true", help="a flat sample under a point light instead of a sphere")
    parser.add_argument("--traversal", action="store_true", help="a traversal sheet (rows: parameters, ±3σ)")
    parser.add_argument("--umap-grid", type=int, metavar="N", help="the paper's UMAP figure of a library: the map "
                        "with its materials and N×N sample points, and the N×N sheet rendered from them (.png)")
    parser.add_argument("--exposure", type=float, help="PNG exposure (default: automatic)")
    parser.add_argument("--compare", type=Path, metavar="SOURCE",
                        help="also render this MERL .binary or RGL .bsdf file the same way and print ΔE ITP, "
                        "ΔE 2000 and PSNR against it")
    parser.add_argument("--mitsuba", type=Path, metavar="SCENE",
                        help="render a Mitsuba 3 scene (.xml or .json) instead of IN, with its bvae/merl BSDFs")
    parser.add_argument("--spp", type=int, help="with --mitsuba: samples per pixel (default: the scene's)")
    parser.add_argument("--variant", default="llvm_ad_rgb",
                        help="with --mitsuba: Mitsuba variant (default llvm_ad_rgb, else scalar_rgb with a warning)")
    parser.add_argument("--force", action="store_true", help="replace an existing output file")
    parser.set_defaults(handler=run)


def _load(path: Path, material: str | None) -> tuple[Any, Any]:
    """(material to render, (library record, decoder) or None)."""
    with open(path, "rb") as stream:
        head = stream.read(8)
    from brdfcodec.format.bvae import MAGIC

    if head != MAGIC:
        from brdfcodec.io.inputs import read_measured

        if material is not None:
            raise ValueError(f"{path}: --material applies to .bvae files only")
        return read_measured(path), None  # a MERL .binary, or an RGL .bsdf tabulated on the MERL grid
    from brdfcodec.codec import MaterialLibrary

    with MaterialLibrary(path) as library:
        if material is None:
            if len(library) != 1:
                from brdfcodec.cli.usage import UsageError

                raise UsageError(f"{path}: holds {len(library)} materials; name one with --material")
            material = library.names[0]
        decoded = library[material]
        return decoded, decoded


def _environment(spec: str) -> Any:
    from brdfcodec.render.preview import Environment, sky_environment

    if spec == "sky":
        return sky_environment()
    from brdfcodec.io.exr import read_exr_rgb

    parts = read_exr_rgb(spec)
    return Environment.from_latlong(next(iter(parts.values())))


def run(args: argparse.Namespace) -> int:
    """Decode (if needed), render and write."""
    from brdfcodec.render.images import write_image, write_png
    from brdfcodec.render.preview import render_flat, render_sphere, render_sphere_environment, traversal_sheet

    if args.mitsuba is not None:
        from brdfcodec.render.mitsuba_scene import render_command

        return render_command(args)
    if args.input is None:
        print("bvae render: error: name the material to render (IN), or a scene with --mitsuba SCENE",
              file=sys.stderr)
        return 2  # a usage error, as argparse's own
    if args.size < 8 or args.size > 4096:
        raise ValueError("--size must be between 8 and 4096 pixels")
    require_output_type(args.output, "render", "an image", (".png", ".exr"))
    check_output_path(args.output, overwrite=args.force)
    if args.umap_grid is not None:
        from brdfcodec.studio.cli_support import run_umap_grid

        return run_umap_grid(args)
    material, decoded = _load(args.input, args.material)
    start = time.perf_counter()
    if decoded is not None:
        decoded.reflectance()  # decode now, so the timings below are apart
    decode_s = time.perf_counter() - start
    start = time.perf_counter()
    if args.traversal:
        if decoded is None:
            raise ValueError("--traversal needs a .bvae material (a latent code to traverse)")
        if args.output.suffix.lower() != ".png":
            raise ValueError("a traversal sheet is written as .png")
        sheet = traversal_sheet(decoded, size=max(32, args.size // 3), light=args.light)
        write_png(args.output, sheet, overwrite=args.force)
        print(f"wrote {args.output} (traversal sheet, {time.perf_counter() - start:.2f} s)")
        return 0
    environment = _environment(args.env) if args.env else None

    def view(subject: Any) -> np.ndarray:
        if environment is not None:
            return render_sphere_environment(subject, environment, size=args.size)
        if args.flat:
            return render_flat(subject, size=args.size)
        return render_sphere(subject, size=args.size, light=args.light)

    image = view(material)
    render_s = time.perf_counter() - start
    if args.compare is not None:
        from brdfcodec.io.inputs import read_measured
        from brdfcodec.render.image_metrics import compare_images

        error = compare_images(view(read_measured(args.compare)), image)
        if args.exposure is None:
            args.exposure = error.exposure  # same exposure for both, the reference's
        print(f"against {args.compare}: ΔE ITP mean {error.delta_e_itp_mean:.3f} (p95 {error.delta_e_itp_p95:.3f}), "
              f"ΔE 2000 mean {error.delta_e_2000_mean:.3f} (p95 {error.delta_e_2000_p95:.3f}), "
              f"PSNR {error.psnr_db:.2f} dB")
    exposure = write_image(args.output, image, exposure=args.exposure, overwrite=args.force)
    print(f"wrote {args.output} ({args.size}x{args.size}; decode {decode_s:.2f} s, render {render_s:.2f} s"
          f"{f', exposure {exposure:.3g}' if args.output.suffix.lower() == '.png' else ''})")
    return 0
