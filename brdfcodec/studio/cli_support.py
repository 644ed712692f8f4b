"""``bvae render LIB.bvae --umap-grid N -o FIG.png``: the command side of :mod:`brdfcodec.studio.figure`."""

from __future__ import annotations

import argparse
import time

__all__ = ["run_umap_grid"]


def run_umap_grid(args: argparse.Namespace) -> int:
    """Write the UMAP figure of the library ``args.input`` (every material on the map)."""
    from brdfcodec.format.bvae import MAGIC
    from brdfcodec.studio.catalogue import Catalogue
    from brdfcodec.studio.figure import write_umap_figure

    if args.output.suffix.lower() != ".png":
        raise ValueError(f"{args.output}: the UMAP figure is written as .png")
    if args.material is not None or args.traversal or args.env or args.flat or args.compare:
        raise ValueError("--umap-grid maps a whole library; it takes no --material, --traversal, --env, --flat "
                         "or --compare")
    with open(args.input, "rb") as stream:
        if stream.read(len(MAGIC)) != MAGIC:
            raise ValueError(f"{args.input}: --umap-grid needs a .bvae library")
    start = time.perf_counter()
    catalogue = Catalogue([args.input])
    write_umap_figure(args.output, catalogue, args.umap_grid, overwrite=args.force,
                      tile=max(32, min(args.size, 128) // 2), light=args.light)
    print(f"wrote {args.output} (UMAP of {len(catalogue.materials)} materials, {args.umap_grid}x{args.umap_grid} "
          f"samples, {time.perf_counter() - start:.1f} s)")
    return 0
