"""Material tables for renderers: load once, share between shapes, float16 or float32, plus sampling densities.

A renderer's BSDF needs, per material, the reflectance table in the MERL
layout (1/sr, channels last for gathering) and densities to importance-sample
it with: the visible-normal and luminance warps of the material's RGL
``.bsdf`` export (:func:`sampling_warps`, built on first use) and a
distribution of the half-vector elevation θh (:func:`theta_h_marginal`).
:func:`material_tables` builds them from a ``.bvae`` material (decoded once) or a MERL ``.binary``
file, and keeps them in a per-process cache keyed by the file's identity, the
material and the precision, so that every shape of a scene that names the
same material shares one table (the cache holds weak references: a table
lives as long as a BSDF uses it).

Invalid entries (below the horizon, unmeasured) are stored as −1 so that one
array carries both values and validity. float16 tables are divided by a
per-table scale when the largest value exceeds float16's range (sharp
analytic lobes reach 10⁶ /sr); the BSDF multiplies it back.
"""

from __future__ import annotations

import os
import threading
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_PHI_D, N_THETA_D, N_THETA_H, TABLE_SHAPE
from brdfcodec.io.rgl_writer import RglResolution, rgl_fields
from brdfcodec.representation.mask import horizon_mask

__all__ = [
    "SAMPLING_RESOLUTION",
    "SAMPLING_THETA_D_BINS",
    "MaterialTables",
    "Precision",
    "SamplingWarps",
    "cache_info",
    "cosine_share",
    "load_physical",
    "material_tables",
    "sampling_warps",
    "theta_h_edges",
    "theta_h_marginal",
]

Precision = Literal["float32", "float16"]
#: Largest value a float16 table holds before it is scaled (float16's maximum is 65504).
FLOAT16_CEILING = 30000.0
#: θd bins averaged for the θh marginal: θd < 60°, where the lobe's shape barely depends on θd.
SAMPLING_THETA_D_BINS = 60
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
#: Resolution of the sampling warps: that of the ``.bsdf`` files ``bvae decompress -o x.bsdf`` writes, which Mitsuba's
#: ``measured`` BSDF samples (32 incident elevations, luminance 32²), except the VNDF's 64² instead of 128²: half the
#: time to build (about 1.5 s a material on 2 cores) for the same noise (benchmarks/test_bench_sampling.py).
SAMPLING_RESOLUTION = RglResolution(vndf=64)
# Share of a luminance slice's mean given to every vertex, so that no direction the table reflects into is left
# with a vanishing density (a cosine-weighted share in the BSDF's mixture bounds the weights as well).
_LUMINANCE_FLOOR = 1e-3


def theta_h_edges() -> npt.NDArray[np.float64]:
    """The 91 edges of the θh bins, radians: (i/90)² · π/2 for i = 0…90 (spec/conventions.md §3)."""
    return (np.arange(N_THETA_H + 1) / N_THETA_H) ** 2 * (np.pi / 2)


def theta_h_marginal(physical: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Probabilities of the 90 θh bins for sampling half vectors.

    Bin i gets ρ̄ᵢ · (sin²θ_{i+1} − sin²θ_i) / 2, the integral of ρ̄ᵢ cos θh
    over its band of half vectors (per 2π of azimuth), where ρ̄ᵢ is the mean
    luminance of the valid entries with θd < 60° of that θh bin. A microfacet
    lobe D(h) gives weights ∝ ∫ D cos θh dω, the classic half-vector density.

    Parameters
    ----------
    physical : array_like, shape (3, 90, 90, 180)
        Reflectance in 1/sr, invalid entries negative.

    Returns
    -------
    ndarray of float64, shape (90,)
        Non-negative weights summing to 1, or all zeros for a black material.
    """
    table = np.asarray(physical, dtype=np.float64)[:, :, :SAMPLING_THETA_D_BINS, :]
    luminance = np.tensordot(_LUMINANCE, np.maximum(table, 0.0), axes=1)
    valid = (table >= 0).all(axis=0)
    count = valid.sum(axis=(1, 2))
    mean = np.divide(np.where(valid, luminance, 0.0).sum(axis=(1, 2)), count, out=np.zeros(N_THETA_H),
                     where=count > 0)
    band = np.diff(np.sin(theta_h_edges()) ** 2) / 2
    weights = mean * band
    total = weights.sum()
    return weights / total if total > 0 and np.isfinite(total) else np.zeros(N_THETA_H)


def cosine_share(marginal: npt.ArrayLike) -> float:
    """Share of cosine-weighted samples to mix with half-vector samples, from a θh marginal.

    ``2 · P(θh > 45°)`` clipped to [0.1, 1]: a Lambertian material (whose
    marginal puts half its mass beyond 45°) is sampled by cosine alone, a
    sharp lobe mostly by its half vectors, with at least 10 % cosine samples
    everywhere so that no direction of non-zero reflectance is missed.

    Parameters
    ----------
    marginal : array_like, shape (90,)
        θh bin probabilities (:func:`theta_h_marginal`); all zeros gives 1.
    """
    weights = np.asarray(marginal, dtype=np.float64)
    if not weights.sum() > 0:
        return 1.0
    beyond = weights[theta_h_edges()[:-1] >= np.pi / 4].sum() / weights.sum()
    return float(np.clip(2.0 * beyond, 0.1, 1.0))


@dataclass(frozen=True)
class SamplingWarps:
    """Densities on the unit square, per incident elevation, to importance-sample a material by.

    Those of the material's RGL ``.bsdf`` export (:func:`brdfcodec.io.rgl_writer.rgl_fields`), sampled as
    Mitsuba's ``measured`` BSDF samples them: a uniform point is warped by the luminance density, the result
    by the VNDF density to a microfacet normal m = (u_θ, u_φ), and ωo is ωi reflected about m. Both
    densities are interpolated linearly between incident elevations.

    Attributes
    ----------
    theta_i : ndarray of float32, shape (T,)
        Incident elevations, radians, uniform on [0, π/2].
    vndf : ndarray of float32, shape (T, V, V)
        Density of normals on the unit square (rows: u_φ = (φm − φi) / 2π + 1/2; columns:
        u_θ = sqrt(θm / (π/2))), bilinear between vertices, positive sum per slice.
    luminance : ndarray of float32, shape (T, L, L)
        Density of the points the VNDF warp takes (rows: second coordinate), positive sum per slice.
    """

    theta_i: np.ndarray
    vndf: np.ndarray
    luminance: np.ndarray


def sampling_warps(physical: npt.ArrayLike, resolution: RglResolution | None = None) -> SamplingWarps | None:
    """The VNDF and luminance warps of a material, as its RGL ``.bsdf`` export holds them.

    Parameters
    ----------
    physical : array_like, shape (3, 90, 90, 180)
        Reflectance in 1/sr; negative entries are invalid (left out).
    resolution : RglResolution, optional
        Table sizes; :data:`SAMPLING_RESOLUTION` (the export's) by default.

    Returns
    -------
    SamplingWarps or None
        None for a material with no positive valid entry or non-finite values (nothing to sample by).
    """
    table = np.asarray(physical, dtype=np.float64)
    valid = (table >= 0) & horizon_mask()[None]
    reflectance = np.where(valid, table, 0.0)
    if not np.isfinite(reflectance).all() or not (reflectance > 0).any():
        return None
    fields = rgl_fields(reflectance, valid, resolution=resolution or SAMPLING_RESOLUTION)
    densities = []
    for name in ("vndf", "luminance"):
        density = np.maximum(fields[name][0].astype(np.float64), 0.0)
        mean = density.mean(axis=(1, 2), keepdims=True)
        if not (np.isfinite(density).all() and (mean > 0).all()):
            return None
        if name == "luminance":
            density = density + _LUMINANCE_FLOOR * mean
        densities.append(np.ascontiguousarray(density / mean, dtype=np.float32))
    return SamplingWarps(fields["theta_i"].astype(np.float32), densities[0], densities[1])


@dataclass(eq=False)
class MaterialTables:
    """One material ready for a renderer.

    Attributes
    ----------
    name : str
        Material name.
    source : str
        The file it came from.
    values : ndarray, shape (90 · 90 · 180 · 3,), or None
        Reflectance / ``scale`` in 1/sr, channels last
        (index ``((iθh · 90 + iθd) · 180 + iφd) · 3 + c``); invalid entries −1.
        None once a renderer holds its own copy (:meth:`release_host`).
    scale : float
        Multiply a value by this to get 1/sr (1 unless a float16 table had to be scaled).
    marginal : ndarray, shape (90,)
        θh bin probabilities (:func:`theta_h_marginal`).
    precision : {"float32", "float16"}
    device : dict
        What the renderer built from ``values`` (a Dr.Jit array), per variant, set by the renderer.
    device_warps : dict
        What the renderer built from :meth:`warps` (Mitsuba warps), per variant, set by the renderer.
    """

    name: str
    source: str
    values: np.ndarray | None
    scale: float
    marginal: np.ndarray
    precision: Precision
    device: dict[str, Any] = field(default_factory=dict)
    device_warps: dict[str, Any] = field(default_factory=dict)
    nbytes: int = 0  # bytes of one copy of the table: 8,748,000 in float16, 17,496,000 in float32
    _warps: list[SamplingWarps | None] = field(default_factory=list, repr=False)
    _warps_lock: Any = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self) -> None:
        if self.values is not None:
            self.nbytes = int(self.values.nbytes)

    def host(self) -> np.ndarray:
        """The table as a numpy array (copied back from a renderer's array if the host copy was released)."""
        if self.values is None:
            dtype = np.float16 if self.precision == "float16" else np.float32
            self.values = np.asarray(next(iter(self.device.values())), dtype=dtype)
        return self.values

    def release_host(self) -> None:
        """Drop the numpy copy once a renderer holds the table (halves the memory of vectorised variants)."""
        if self.device:
            self.values = None

    def warps(self) -> SamplingWarps | None:
        """The material's :func:`sampling_warps`, built on the first call (a few seconds) and kept."""
        with self._warps_lock:
            if not self._warps:
                values = self.values if self.values is not None else next(iter(self.device.values()))
                channels_last = np.asarray(values, dtype=np.float32).reshape(N_THETA_H, N_THETA_D, N_PHI_D, 3)
                physical = np.where(channels_last >= 0, channels_last * np.float32(self.scale), np.float32(-1.0))
                self._warps.append(sampling_warps(np.moveaxis(physical, -1, 0)))
            return self._warps[0]


_CACHE: weakref.WeakValueDictionary[tuple[Any, ...], MaterialTables] = weakref.WeakValueDictionary()
_LOCK = threading.Lock()
_DECODES = {"count": 0}


def _is_bvae(path: Path) -> bool:
    from brdfcodec.format.bvae import MAGIC

    with open(path, "rb") as stream:
        return stream.read(len(MAGIC)) == MAGIC


def load_physical(path: str | os.PathLike[str], material: str | None = None,
                  kind: Literal["auto", "bvae", "merl"] = "auto") -> tuple[str, np.ndarray]:
    """Reflectance (1/sr, float32, (3, 90, 90, 180), invalid entries −1) of a ``.bvae`` material or a MERL file.

    Parameters
    ----------
    path : path-like
        A ``.bvae`` file (decoded with the decoder its header names) or a MERL ``.binary``.
    material : str, optional
        Material of a ``.bvae`` library; may be omitted when it holds one. Not allowed for MERL files.
    kind : {"auto", "bvae", "merl"}
        ``auto`` tells the two apart by the file's first bytes.

    Returns
    -------
    (name, table)

    Raises
    ------
    FileNotFoundError, brdfcodec.errors.FileFormatError, KeyError
    """
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"{file}: no such file")
    is_bvae = _is_bvae(file) if kind == "auto" else kind == "bvae"
    if not is_bvae:
        from brdfcodec.io.merl import read_merl

        if material is not None and kind == "merl":
            raise ValueError(f"{file}: a MERL file holds one material; 'material' applies to .bvae files")
        brdf = read_merl(file)
        table = np.where(brdf.mask, brdf.reflectance(), -1.0).astype(np.float32)
        return material or file.stem, table
    from brdfcodec.codec import MaterialLibrary
    from brdfcodec.representation.mask import horizon_mask

    with MaterialLibrary(file) as library:
        if material is None:
            if len(library) != 1:
                raise ValueError(f"{file}: holds {len(library)} materials; name one with 'material'")
            material = library.names[0]
        if material not in library:
            raise KeyError(f"{file}: no material named {material!r}")
        decoded = library[material]
        physical = decoded.reflectance()
        _DECODES["count"] += 1
        table = np.where(horizon_mask()[None], physical, np.float32(-1.0)).astype(np.float32)
    return material, table


def _file_key(path: Path) -> tuple[str, int, int]:
    stat = path.stat()
    return (str(path.resolve()), stat.st_mtime_ns, stat.st_size)


def _build(name: str, source: str, table: np.ndarray, precision: Precision) -> MaterialTables:
    if table.shape != TABLE_SHAPE:
        raise ValueError(f"{source}: table of shape {table.shape}, expected {TABLE_SHAPE}")
    channels_last = np.ascontiguousarray(np.moveaxis(table, 0, -1)).reshape(-1)
    peak = float(channels_last.max(initial=0.0))
    if not np.isfinite(peak):
        raise ValueError(f"{source}: material {name!r} has non-finite reflectance")
    scale = 1.0
    if precision == "float16":
        scale = max(1.0, peak / FLOAT16_CEILING)
        stored = np.where(channels_last >= 0, channels_last / scale, -1.0).astype(np.float16)
    elif precision == "float32":
        stored = channels_last.astype(np.float32)
    else:
        raise ValueError(f"precision must be 'float32' or 'float16', got {precision!r}")
    return MaterialTables(name, source, stored, scale, theta_h_marginal(table), precision)


def material_tables(
    path: str | os.PathLike[str],
    material: str | None = None,
    *,
    precision: Precision = "float32",
    kind: Literal["auto", "bvae", "merl"] = "auto",
    loader: Callable[..., tuple[str, np.ndarray]] = load_physical,
) -> MaterialTables:
    """The tables of one material, decoded once and shared while any user holds them.

    Parameters
    ----------
    path : path-like
        ``.bvae`` or MERL ``.binary`` file.
    material : str, optional
        Material of a ``.bvae`` library.
    precision : {"float32", "float16"}, default "float32"
        float16 halves the memory (8.7 MB instead of 17.5 MB a material).
    kind : {"auto", "bvae", "merl"}

    Returns
    -------
    MaterialTables
        The same object for every call with the same file (same path,
        modification time and size), material and precision, as long as a
        previous result is still referenced.
    """
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"{file}: no such file")
    key = (*_file_key(file), material, precision, kind)
    with _LOCK:
        cached = _CACHE.get(key)
        if cached is not None:
            return cached
        name, table = loader(file, material, kind)
        tables = _build(name, str(file), table, precision)
        _CACHE[key] = tables
        return tables


def cache_info() -> dict[str, int]:
    """``{"decodes": .bvae materials decoded so far, "live": tables currently shared}``."""
    return {"decodes": _DECODES["count"], "live": len(_CACHE)}
