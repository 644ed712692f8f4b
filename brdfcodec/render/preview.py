"""A small vectorised renderer for previews: a sphere or a flat sample under a directional light or an environment.

Units: the light's ``irradiance`` is RGB in W·m⁻² on a surface facing it
(any consistent unit works), reflectance in 1/sr, so pixel values are
radiance in W·m⁻²·sr⁻¹. The camera is orthographic, looking down −z; the
image's x axis points right and y up. No shadows or interreflections (a
convex object lit from outside has neither under a directional light).

Materials are anything with the MERL layout: a
:class:`~brdfcodec.codec.DecodedMaterial`, a :class:`~brdfcodec.io.merl.MerlBRDF`,
or a physical table ``(3, 90, 90, 180)`` in 1/sr with an optional mask.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import TABLE_SHAPE
from brdfcodec.representation.lookup import lookup
from brdfcodec.representation.mask import horizon_mask

__all__ = [
    "Environment",
    "MaterialTable",
    "material_table",
    "render_flat",
    "render_sphere",
    "render_sphere_environment",
    "sky_environment",
    "traversal_sheet",
]

LookupMode = Literal["nearest", "trilinear"]


@dataclass(frozen=True)
class MaterialTable:
    """Physical reflectance (1/sr) in MERL layout, with the mask of valid entries."""

    reflectance: np.ndarray
    mask: np.ndarray

    def eval(self, wi: np.ndarray, wo: np.ndarray, mode: LookupMode = "nearest") -> np.ndarray:
        """Reflectance at local-frame direction pairs, shape (..., 3)."""
        return lookup(self.reflectance, wi, wo, mode=mode, mask=self.mask)


def material_table(material: Any) -> MaterialTable:
    """A :class:`MaterialTable` from a decoded material, a MerlBRDF, or a physical array."""
    if isinstance(material, MaterialTable):
        return material
    if hasattr(material, "reflectance") and hasattr(material, "record"):  # DecodedMaterial
        mask = np.broadcast_to(horizon_mask(), TABLE_SHAPE)
        return MaterialTable(material.reflectance(), mask)
    if hasattr(material, "reflectance") and hasattr(material, "mask"):  # MerlBRDF
        return MaterialTable(material.reflectance(), material.mask)
    array = np.asarray(material)
    if array.shape != TABLE_SHAPE:
        raise TypeError(f"cannot render {type(material).__name__}: expected a material or a {TABLE_SHAPE} table")
    return MaterialTable(array, np.broadcast_to(horizon_mask(), TABLE_SHAPE))


def _unit(v: npt.ArrayLike) -> np.ndarray:
    array = np.asarray(v, dtype=np.float64)
    norm = np.linalg.norm(array, axis=-1, keepdims=True)
    if not np.all(norm > 0):
        raise ValueError(f"direction must be non-zero, got {v}")
    return array / norm


def _frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent and bitangent for each normal (any frame serves an isotropic BRDF)."""
    helper = np.where(np.abs(normals[..., 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    tangent = np.cross(helper, normals)
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    return tangent, np.cross(normals, tangent)


def _to_local(v: np.ndarray, n: np.ndarray, t: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([(v * t).sum(-1), (v * b).sum(-1), (v * n).sum(-1)], axis=-1)


def _sphere(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Normals of a unit sphere filling the image, and the coverage mask."""
    if size < 2:
        raise ValueError(f"size must be at least 2 pixels, got {size}")
    coords = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(coords, -coords)
    r2 = x * x + y * y
    inside = r2 < 1.0
    z = np.sqrt(np.clip(1 - r2, 0, None))
    return np.stack([x, y, z], axis=-1)[inside], inside


def render_sphere(
    material: Any,
    *,
    size: int = 256,
    light: Sequence[float] = (-1.0, 1.0, 1.0),
    irradiance: Sequence[float] | float = 1.0,
    mode: LookupMode = "nearest",
    background: float = 0.0,
) -> npt.NDArray[np.float32]:
    """A sphere under a directional light, orthographic view along −z.

    Parameters
    ----------
    material : DecodedMaterial, MerlBRDF, MaterialTable or array
    size : int, default 256
        Image width and height, pixels.
    light : 3 floats, default (−1, 1, 1)
        Direction towards the light (normalised here).
    irradiance : float or 3 floats, default 1
        RGB irradiance on a surface facing the light.
    mode : {"nearest", "trilinear"}
        Table lookup.
    background : float, default 0

    Returns
    -------
    ndarray of float32, shape (size, size, 3)
        Radiance, finite and ≥ 0 for a finite non-negative material.
    """
    table = material_table(material)
    normals, inside = _sphere(size)
    wi_world = _unit(light)
    t, b = _frames(normals)
    wi = _to_local(np.broadcast_to(wi_world, normals.shape), normals, t, b)
    wo = _to_local(np.broadcast_to([0.0, 0.0, 1.0], normals.shape), normals, t, b)
    cos_i = np.clip(wi[:, 2], 0, None)
    radiance = table.eval(wi, wo, mode) * (cos_i[:, None] * np.asarray(irradiance, dtype=np.float64))
    image = np.full((size, size, 3), background, dtype=np.float32)
    image[inside] = np.maximum(radiance, 0)
    return image


def render_flat(
    material: Any,
    *,
    size: int = 256,
    light_position: Sequence[float] = (0.0, 1.2, 1.0),
    camera_position: Sequence[float] = (0.0, -1.5, 1.5),
    intensity: Sequence[float] | float = 2.0,
    mode: LookupMode = "nearest",
) -> npt.NDArray[np.float32]:
    """A flat square sample (z = 0, side 2) under a point light, seen from a camera position.

    The image shows the sample's surface in its own coordinates (pixel (i, j)
    is the point x = −1…1, y = 1…−1); each point gets the view and light
    directions of its position, so the highlight moves across the sample.
    ``intensity`` is the point light's RGB intensity (W·sr⁻¹); the result is
    radiance with inverse-square falloff.
    """
    table = material_table(material)
    coords = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(coords, -coords)
    points = np.stack([x, y, np.zeros_like(x)], axis=-1).reshape(-1, 3)
    to_light = np.asarray(light_position, dtype=np.float64) - points
    distance2 = (to_light**2).sum(-1)
    wi = to_light / np.sqrt(distance2)[:, None]
    wo = _unit(np.asarray(camera_position, dtype=np.float64) - points)
    cos_i = np.clip(wi[:, 2], 0, None)
    radiance = table.eval(wi, wo, mode) * (cos_i / distance2)[:, None] * np.asarray(intensity, dtype=np.float64)
    return np.maximum(radiance, 0).reshape(size, size, 3).astype(np.float32)


@dataclass(frozen=True)
class Environment:
    """Distant lighting as a set of directions with radiance × solid angle (RGB, W·m⁻²)."""

    directions: np.ndarray  # (K, 3) unit vectors, world frame (z towards the camera, y up)
    weights: np.ndarray  # (K, 3) radiance · solid angle

    @classmethod
    def from_latlong(cls, image: npt.ArrayLike, *, resolution: tuple[int, int] = (8, 16)) -> Environment:
        """From an equirectangular (lat-long) radiance map (H, W, 3), averaged down to ``resolution`` cells.

        Row 0 is straight up (+y), the centre column looks towards −z (away
        from the camera, behind the object).
        """
        env = np.asarray(image, dtype=np.float64)
        if env.ndim != 3 or env.shape[2] != 3 or not np.isfinite(env).all() or (env < 0).any():
            raise ValueError("an environment map must be a finite, non-negative (H, W, 3) image")
        rows, cols = resolution
        h, w = env.shape[:2]
        if h < rows or w < cols:
            raise ValueError(f"environment map {h}×{w} is smaller than the resolution {rows}×{cols}")
        row_edges = np.linspace(0, h, rows + 1).astype(int)
        col_edges = np.linspace(0, w, cols + 1).astype(int)
        cells = np.array([[env[row_edges[i]:row_edges[i + 1], col_edges[j]:col_edges[j + 1]].mean(axis=(0, 1))
                           for j in range(cols)] for i in range(rows)])
        theta = (np.arange(rows) + 0.5) / rows * np.pi  # from +y
        phi = (np.arange(cols) + 0.5) / cols * 2 * np.pi - np.pi  # 0 = −z
        th, ph = np.meshgrid(theta, phi, indexing="ij")
        directions = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], axis=-1)
        solid_angle = (np.cos(np.arange(rows) * np.pi / rows) - np.cos(np.arange(1, rows + 1) * np.pi / rows))
        solid_angle = solid_angle[:, None] * (2 * np.pi / cols)
        weights = cells * np.broadcast_to(solid_angle, (rows, cols))[..., None]
        keep = weights.sum(-1) > 0
        return cls(directions[keep], weights[keep])


def sky_environment(*, sun: Sequence[float] = (-0.5, 0.8, 0.6), sun_strength: float = 30.0) -> Environment:
    """A built-in environment: a blue-to-white sky over a grey ground (8×16 cells) plus a small sun."""
    rows, cols = 64, 128
    theta = (np.arange(rows) + 0.5) / rows * np.pi
    up = np.cos(theta)[:, None, None]
    sky = np.where(up > 0, (1 - up) * np.array([0.9, 0.95, 1.0]) + up * np.array([0.25, 0.45, 0.9]),
                   np.array([0.25, 0.22, 0.2]))
    image = np.broadcast_to(sky, (rows, cols, 3)).copy()
    env = Environment.from_latlong(image)
    sun_dir = _unit(sun)
    sun_weight = np.full((1, 3), 0.068 * sun_strength)  # radiance × solid angle of a small, bright disc
    return Environment(np.concatenate([env.directions, sun_dir[None]]), np.concatenate([env.weights, sun_weight]))


def render_sphere_environment(
    material: Any,
    environment: Environment | None = None,
    *,
    size: int = 256,
    mode: LookupMode = "nearest",
    chunk: int = 16384,
) -> npt.NDArray[np.float32]:
    """A sphere lit by an environment (sum over its directions; no shadowing), orthographic view along −z."""
    table = material_table(material)
    env = environment if environment is not None else sky_environment()
    normals, inside = _sphere(size)
    t, b = _frames(normals)
    wo = _to_local(np.broadcast_to([0.0, 0.0, 1.0], normals.shape), normals, t, b)
    radiance = np.zeros((normals.shape[0], 3))
    for direction, weight in zip(env.directions, env.weights, strict=True):
        cos_world = normals @ direction
        lit = cos_world > 0
        if not lit.any():
            continue
        idx = np.nonzero(lit)[0]
        for start in range(0, idx.size, chunk):
            part = idx[start : start + chunk]
            wi = _to_local(np.broadcast_to(direction, (part.size, 3)), normals[part], t[part], b[part])
            radiance[part] += table.eval(wi, wo[part], mode) * (cos_world[part, None] * weight)
    image = np.zeros((size, size, 3), dtype=np.float32)
    image[inside] = np.maximum(radiance, 0)
    return image


def traversal_sheet(
    material: Any,
    *,
    size: int = 85,
    light: Sequence[float] = (-1.0, 1.0, 1.0),
    steps: Sequence[float] = (-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0),
) -> npt.NDArray[np.uint8]:
    """A labelled sheet of spheres: one row per latent parameter, traversed over ``steps`` (prior σ).

    Parameters
    ----------
    material : brdfcodec.codec.DecodedMaterial
        A decoded material (its record and decoder are traversed).
    size : int, default 85
        Pixels per sphere.
    light : (float, float, float)
        Direction towards the light.
    steps : sequence of float
        Offsets of the traversed parameter, in prior σ; the middle column is the material itself when 0 is in it.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        sRGB, one exposure for the whole sheet (from the unedited spheres' column).
    """
    from brdfcodec.codec import DecodedMaterial
    from brdfcodec.edit.latent_edits import parameter_vector, traverse
    from brdfcodec.models.parameters import distinct_labels
    from brdfcodec.render.images import auto_exposure, compose_sheet, encode_srgb

    record, decoder = material.record, material.decoder
    steps = [float(s) for s in steps]
    manifest = decoder.manifest
    effects = manifest.parameters.get("dimensions", []) if manifest is not None else []
    names = distinct_labels(effects) if len(effects) == decoder.latent_dim else [e.get("label", "") for e in effects]
    rows, labels = [], []
    for dim in range(parameter_vector(record).size):
        edited = traverse(record, dim, steps)
        rows.append([render_sphere(DecodedMaterial(r, decoder), size=size, light=tuple(light)) for r in edited])
        label = names[dim] if dim < len(names) else "grafted green"
        labels.append(f"z{dim + 1}: {label}")
    middle = len(steps) // 2
    exposure = auto_exposure(np.concatenate([row[middle] for row in rows]))
    tiles = [[encode_srgb(img, exposure=exposure) for img in row] for row in rows]
    name = manifest.name if manifest is not None else "decoder in memory"
    return compose_sheet(tiles, row_labels=labels, column_labels=[f"{s:+g}σ" for s in steps],
                         title=f"{record.name}: latent traversal ({name})",
                         label_width=max(260, 6 * max(len(text) for text in labels) + 16))
