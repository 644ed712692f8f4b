"""The manifold explorer's map: a UMAP embedding (umap-learn) of a library's latents, and its inverse.

The paper maps the latents to 2-D with UMAP and maps a dragged point back
with UMAP's inverse transform. One call of ``inverse_transform`` costs
about the same whatever the number of points (it rebuilds its search
structures), far too slow for a live drag, so the map tabulates the inverse
on a regular grid over the map once and the explorer interpolates it bilinearly. The embedding
and the grid are cached as ``.npz`` (no pickles) in the user cache folder
(``$BRDFCODEC_CACHE_DIR``, else ``$XDG_CACHE_HOME/brdfcodec``, else
``~/.cache/brdfcodec``), keyed by the codes, the names, the decoder and the
UMAP settings, so a second start is instant.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.io.atomic import atomic_output

__all__ = [
    "ManifoldMap",
    "cache_folder",
    "cached_manifold",
    "fit_umap",
    "fit_manifold",
    "latent_at",
    "umap_module",
]

#: Settings of the embedding (part of the cache key).
UMAP_SETTINGS: dict[str, Any] = {"n_neighbors": 15, "min_dist": 0.1, "metric": "euclidean", "random_state": 0}
#: Points per side of the tabulated inverse transform (48 intervals: 7×7 samples fall on grid nodes).
GRID_SIZE = 49
_MARGIN = 0.05


@dataclass(frozen=True)
class ManifoldMap:
    """A 2-D map of latent codes and its tabulated inverse.

    Attributes
    ----------
    names : list of str
        Material ids, in the order of ``embedding``.
    embedding : ndarray, shape (N, 2)
        UMAP coordinates of the materials.
    bounds : tuple of 4 floats
        ``(x0, x1, y0, y1)``: the map's extent (the embedding plus a 5 % margin).
    grid : ndarray of float32, shape (G, G, D)
        ``inverse_transform`` at ``x = linspace(x0, x1, G)[i]``, ``y = linspace(y0, y1, G)[j]``,
        indexed ``[j, i]``.
    """

    names: list[str]
    embedding: np.ndarray
    bounds: tuple[float, float, float, float]
    grid: np.ndarray

    def as_json(self) -> dict[str, Any]:
        """For the client: points, bounds and the grid (row-major, ``[j][i][d]`` flattened)."""
        return {
            "points": [{"id": n, "x": float(x), "y": float(y)} for n, (x, y) in zip(self.names, self.embedding,
                                                                                     strict=True)],
            "bounds": list(self.bounds),
            "grid_size": int(self.grid.shape[0]),
            "grid": [round(float(v), 5) for v in self.grid.reshape(-1)],
        }


def umap_module() -> Any:
    """``umap`` (umap-learn), imported quietly; a clear error when the ``studio`` extra is missing."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import umap
    except ImportError as error:  # pragma: no cover - depends on the installation
        raise ImportError('the manifold explorer needs umap-learn: pip install "brdfcodec[studio]"') from error
    return umap


def fit_umap(codes: np.ndarray, *, settings: dict[str, Any] | None = None) -> Any:
    """A fitted ``umap.UMAP`` of codes (N, D); ``n_neighbors`` is capped at N − 1.

    Raises
    ------
    ValueError
        Fewer than 4 codes (UMAP needs neighbours), or non-finite codes.
    """
    codes = np.asarray(codes, dtype=np.float32)
    if codes.ndim != 2 or codes.shape[0] < 4:
        raise ValueError(f"a UMAP map needs at least 4 materials, got {codes.shape[0] if codes.ndim == 2 else 0}")
    if not np.isfinite(codes).all():
        raise ValueError("latent codes must be finite")
    options = {**UMAP_SETTINGS, **(settings or {})}
    options["n_neighbors"] = min(int(options["n_neighbors"]), codes.shape[0] - 1)
    umap = umap_module()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "n_jobs overridden by random_state", numba notices
        return umap.UMAP(**options).fit(codes)


def inverse(model: Any, points: np.ndarray, limit: float) -> np.ndarray:
    """``model.inverse_transform(points)`` as float32, non-finite values replaced and clipped to ±limit."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        codes = np.asarray(model.inverse_transform(np.asarray(points, dtype=np.float64)), dtype=np.float64)
    return np.clip(np.nan_to_num(codes, nan=0.0), -limit, limit).astype(np.float32)


def map_bounds(embedding: np.ndarray) -> tuple[float, float, float, float]:
    """The embedding's extent plus a 5 % margin on each side."""
    lo, hi = embedding.min(0), embedding.max(0)
    pad = np.maximum(hi - lo, 1e-6) * _MARGIN
    return (float(lo[0] - pad[0]), float(hi[0] + pad[0]), float(lo[1] - pad[1]), float(hi[1] + pad[1]))


def fit_manifold(codes: np.ndarray, names: Sequence[str], *, grid_size: int = GRID_SIZE,
                 limit: float = 20.0) -> ManifoldMap:
    """Fit UMAP to codes and tabulate its inverse transform on a ``grid_size``² grid over the map."""
    model = fit_umap(codes)
    embedding = np.asarray(model.embedding_, dtype=np.float64)
    bounds = map_bounds(embedding)
    xs = np.linspace(bounds[0], bounds[1], grid_size)
    ys = np.linspace(bounds[2], bounds[3], grid_size)
    points = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)  # [j, i] order
    grid = inverse(model, points, limit).reshape(grid_size, grid_size, -1)
    return ManifoldMap(list(names), embedding, bounds, grid)


def latent_at(manifold: ManifoldMap, x: float, y: float) -> np.ndarray:
    """Bilinear interpolation of the tabulated inverse at map position (x, y) (clamped to the map)."""
    x0, x1, y0, y1 = manifold.bounds
    g = manifold.grid.shape[0]
    u = float(np.clip((x - x0) / (x1 - x0), 0.0, 1.0)) * (g - 1)
    v = float(np.clip((y - y0) / (y1 - y0), 0.0, 1.0)) * (g - 1)
    i, j = min(int(u), g - 2), min(int(v), g - 2)
    fu, fv = u - i, v - j
    grid = manifold.grid.astype(np.float64)
    top = grid[j, i] * (1 - fu) + grid[j, i + 1] * fu
    bottom = grid[j + 1, i] * (1 - fu) + grid[j + 1, i + 1] * fu
    return (top * (1 - fv) + bottom * fv).astype(np.float32)


def cache_folder() -> Path:
    """Where fitted maps are cached (see the module's docstring)."""
    if os.environ.get("BRDFCODEC_CACHE_DIR"):
        return Path(os.environ["BRDFCODEC_CACHE_DIR"]) / "umap"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "brdfcodec" / "umap"


def _cache_key(codes: np.ndarray, names: Sequence[str], decoder_sha256: str, grid_size: int) -> str:
    umap = umap_module()
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(codes, dtype=np.float32).tobytes())
    digest.update(json.dumps([list(names), decoder_sha256, UMAP_SETTINGS, grid_size,
                              getattr(umap, "__version__", "?")]).encode())
    return digest.hexdigest()[:32]


def cached_manifold(codes: np.ndarray, names: Sequence[str], decoder_sha256: str, *,
                    grid_size: int = GRID_SIZE, folder: Path | None = None) -> ManifoldMap:
    """:func:`fit_manifold`, loaded from the cache when the same codes, names, decoder and settings were fitted."""
    folder = folder or cache_folder()
    path = folder / f"{_cache_key(codes, names, decoder_sha256, grid_size)}.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as data:
                names_stored = [str(n) for n in data["names"]]
                if names_stored == list(names):
                    return ManifoldMap(names_stored, data["embedding"], tuple(float(b) for b in data["bounds"]),
                                       data["grid"])
        except (OSError, ValueError, KeyError):
            pass  # a damaged cache entry is refitted and replaced
    manifold = fit_manifold(codes, names, grid_size=grid_size)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with atomic_output(path, overwrite=True) as tmp, open(tmp, "wb") as stream:
            np.savez(stream, names=np.asarray(manifold.names), embedding=manifold.embedding,
                     bounds=np.asarray(manifold.bounds), grid=manifold.grid)
    except OSError:
        pass  # an unwritable cache only costs the next start a refit
    return manifold
