"""The paper's UMAP figure: the map of a library's latents with its materials and N×N sample points, and the
N×N sheet of spheres rendered from the inverse transform at those points (``bvae render --umap-grid N``).

The samples span the whole map (its extent plus the 5 % margin, as the
explorer shows it). Their codes come from the map's tabulated inverse
transform (:mod:`brdfcodec.studio.manifold`): exact UMAP ``inverse_transform``
values when the sample points fall on the 49×49 grid (N = 2, 3, 4, 5, 7, 9,
13, 17, 25 or 49), bilinear between grid nodes otherwise.
"""

from __future__ import annotations

import io
import os
from typing import Any

import numpy as np

__all__ = ["sample_points", "umap_figure", "write_umap_figure"]


def sample_points(bounds: tuple[float, float, float, float], n: int) -> np.ndarray:
    """N×N points over the map, shape (n, n, 2), row 0 at the top (largest y), column 0 at the left."""
    x0, x1, y0, y1 = bounds
    xs = np.linspace(x0, x1, n)
    ys = np.linspace(y1, y0, n)
    return np.stack(np.meshgrid(xs, ys), axis=-1)


def umap_figure(catalogue: Any, n: int, *, tile: int = 64, light: tuple[float, float, float] = (-1.0, 1.0, 1.0),
                manifold_cache: Any = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Render the figure as 8-bit RGB pixels.

    Parameters
    ----------
    catalogue : Catalogue
        The library (its materials are the map's points).
    n : int
        Samples per side, 2 to 12.
    tile : int
        Sphere size in the sheet, pixels.

    Returns
    -------
    pixels : ndarray of uint8, shape (H, W, 3)
    info : dict
        ``"codes"`` (n, n, D) sampled latents, ``"points"`` (n, n, 2), ``"exposure"``.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from PIL import Image

    from brdfcodec.codec import DecodedMaterial
    from brdfcodec.format.bvae import LatentRecord
    from brdfcodec.render.images import auto_exposure, compose_sheet, encode_srgb
    from brdfcodec.render.preview import render_sphere
    from brdfcodec.studio.manifold import cached_manifold, latent_at

    if not 2 <= n <= 12:
        raise ValueError(f"--umap-grid must be between 2 and 12, got {n}")
    manifold = cached_manifold(catalogue.codes(), catalogue.ids(), catalogue.decoder.reference.sha256,
                               folder=manifold_cache)
    points = sample_points(manifold.bounds, n)
    codes = np.stack([[latent_at(manifold, x, y) for x, y in row] for row in points])
    renders = [[render_sphere(DecodedMaterial(LatentRecord("sample", z, np.ones_like(z)), catalogue.decoder),
                              size=tile, light=light) for z in row] for row in codes]
    exposure = auto_exposure(np.concatenate([np.concatenate(row, axis=1) for row in renders]))
    tiles = [[encode_srgb(img, exposure=exposure) for img in row] for row in renders]
    sheet = compose_sheet(tiles, row_labels=[f"row {i + 1}" for i in range(n)],
                          column_labels=[f"{j + 1}" for j in range(n)],
                          title=f"UMAP inverse transform, {n}x{n} samples", label_width=60)

    figure, (left, right) = plt.subplots(1, 2, figsize=(16, 8), dpi=100,
                                         gridspec_kw={"width_ratios": [1, sheet.shape[1] / sheet.shape[0]]})
    emb = manifold.embedding
    left.scatter(emb[:, 0], emb[:, 1], s=14, c="#2f6fd0", zorder=3)
    for name, (x, y) in zip(manifold.names, emb, strict=True):
        left.annotate(name.split("/")[-1], (x, y), fontsize=5, xytext=(2, 2), textcoords="offset points",
                      color="#333333")
    flat = points.reshape(-1, 2)
    left.scatter(flat[:, 0], flat[:, 1], s=22, marker="+", c="#d04020", zorder=4)
    for k, (x, y) in enumerate(flat):
        left.annotate(f"{k // n + 1},{k % n + 1}", (x, y), fontsize=5, color="#d04020", xytext=(2, -7),
                      textcoords="offset points")
    x0, x1, y0, y1 = manifold.bounds
    left.set_xlim(x0, x1)
    left.set_ylim(y0, y1)
    left.set_title(f"UMAP of {len(manifold.names)} latents ({catalogue.decoder.reference.name}); "
                   f"+ = {n}x{n} samples (row, column)", fontsize=9)
    left.set_xlabel("UMAP 1")
    left.set_ylabel("UMAP 2")
    right.imshow(sheet)
    right.set_axis_off()
    figure.tight_layout()
    stream = io.BytesIO()
    figure.savefig(stream, format="png")
    plt.close(figure)
    pixels = np.asarray(Image.open(io.BytesIO(stream.getvalue())).convert("RGB"))
    return pixels, {"codes": codes, "points": points, "exposure": exposure}


def write_umap_figure(path: str | os.PathLike[str], catalogue: Any, n: int, *, overwrite: bool = False,
                      tile: int = 64, light: tuple[float, float, float] = (-1.0, 1.0, 1.0)) -> dict[str, Any]:
    """Write :func:`umap_figure` as PNG, atomically; returns its info."""
    from brdfcodec.render.images import write_png

    if not os.fspath(path).lower().endswith(".png"):
        raise ValueError(f"{path}: the UMAP figure is written as .png")
    pixels, info = umap_figure(catalogue, n, tile=tile, light=light)
    write_png(path, pixels, overwrite=overwrite)
    return info
