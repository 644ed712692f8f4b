"""Writing RGL ``.bsdf`` files: a MERL-layout table as the adaptive parameterisation of Dupuy and Jakob 2018.

The RGL material database stores each measurement as a Mitsuba *tensor
file* read by Mitsuba 3's built-in ``measured`` BSDF (and by pbrt-v4's and
Falcor's readers of the format). This module builds that file from any table
brdfcodec can decode, with NumPy alone (Mitsuba is used only by the tests and
the study that check the result):

1. **NDF** ``ndf`` — the microfacet distribution D(θm) recovered from the
   retro-reflection f(ω, ω) by the power iteration of Dupuy et al. 2015:
   D(ω) ∝ f(ω, ω) cos θ σ(ω), iterated to the dominant eigenvector and
   normalised so that ∫ D(m) cos θm dm = 1. Tabulated on the format's
   coordinate u = sqrt(θ / (π/2)) (rows: φ, identical for an isotropic file).
2. **Projected area** ``sigma`` — σ(ωi) = ∫ D(m) max(0, ωi·m) dm on the same grid.
3. **VNDF warps** ``vndf`` — per incident elevation θi, a density on the
   unit square (u_θ, u_φ) of the format (φ relative to the incident azimuth,
   the Jacobian 2π² u_θ sin θm included): half the density of the visible
   normals D(m) max(0, ωi·m) / σ(ωi), half the luminance of f(ωi, ωo)
   (nearest-bin lookup, spikes capped) carried to the normals m that reflect
   ωi into ωo. Readers only sample
   and invert this table, so any positive density is valid; the data's own
   lobe places the sample grid's vertices where the material's lobe is at
   this θi, which a single NDF misplaces when the lobe's width changes with
   θi (as in MERL's plastics and paints).
4. **RGB** ``rgb`` — per θi, the reflectance at the *warped* sample
   positions: a vertex s of the n × n sample grid is carried through the
   VNDF warp (the continuous marginal/conditional inversion the readers
   use) to a normal m, the outgoing direction is ωo = reflect(ωi, m), and
   the stored value is f(ωi, ωo) cos θo · 4 σ(ωi) / D(m) (the file's
   ``jacobian`` flag is 1: readers multiply by D(m) / (4 σ(ωi)) again).
   Values more than four times the 99th percentile of their θi slice (normals
   the NDF barely weights, where the division by D(m) explodes) are scaled
   down to that bound.
5. **Luminance** ``luminance`` — the luminance (Rec. 709 Y) of those RGB
   values times the ratio of the visible-normal density to the VNDF table's
   density at the warped point (between 0 and 2): readers sample it before
   the VNDF warp, so directions are drawn in proportion to the luminance of
   f cos θo up to the tables' resolution.

f is looked up in the MERL table with :func:`brdfcodec.representation.lookup.lookup`
(``trilinear``, unmeasured entries left out). Values are linear RGB
reflectance in 1/sr (what ``measured`` returns, times cos θo).

Only isotropic RGB materials are written (the MERL grid is isotropic):
``phi_i`` holds the single azimuth 0.
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import TABLE_SHAPE
from brdfcodec.errors import FileFormatError
from brdfcodec.io.atomic import atomic_output, check_output_path
from brdfcodec.io.rgl import TENSOR_FILE_MAGIC
from brdfcodec.representation import reflectance_from_stored
from brdfcodec.representation.lookup import lookup
from brdfcodec.representation.mask import horizon_mask

__all__ = [
    "LUMINANCE_WEIGHTS",
    "MAX_FILE_BYTES",
    "RglResolution",
    "RglWriteError",
    "power_iteration_ndf",
    "rgl_fields",
    "tensor_file_bytes",
    "write_rgl_bsdf",
]

#: Rec. 709 / sRGB luminance weights (Mitsuba's ``luminance()`` of linear RGB).
LUMINANCE_WEIGHTS = (0.212671, 0.715160, 0.072169)

# Mitsuba tensor-file dtype codes (the inverse of brdfcodec.io.rgl's table, for the dtypes written here).
_DTYPE_CODES = {np.dtype("u1"): 1, np.dtype("<u4"): 5, np.dtype("<f4"): 10}
_ALIGNMENT = 8
# Elevation at which a grazing node's BRDF is looked up: the MERL grid has no data at θ = π/2 exactly.
_GRAZING_LIMIT = np.radians(89.5)
_POWER_ITERATIONS = 200
_OUTLIER_FACTOR = 4.0
# Share of each VNDF table given to the data's own reflected lobe (the rest: the NDF's visible normals).
_DATA_WARP_SHARE = 0.5
_EPSILON32 = float(np.finfo(np.float32).eps)
#: Largest file the writer makes, bytes (1 GiB: the RGL database's files are below 2 MB; a VNDF of 2048² at the
#: default 32 elevations is 0.5 GiB). Memory while writing is a few θi slices' worth, whatever the file's size.
MAX_FILE_BYTES = 1 << 30
# Values per chunk of the vectorised steps (sample warps, lookups): bounds their temporaries to tens of MB.
_CHUNK = 1 << 18


class RglWriteError(FileFormatError):
    """A material cannot be written as an RGL ``.bsdf`` file (non-finite, unmeasured or black table)."""


@dataclass(frozen=True)
class RglResolution:
    """Resolutions of the tables of a written ``.bsdf`` file.

    The defaults are those of the RGL database's isotropic files (NDF and
    VNDF 128 samples per axis, luminance and RGB 32 × 32), except ``theta_i``:
    the database stores the incident elevations its instrument measured
    (8 for ``paper_white``); a tabulated material can afford more, and
    readers interpolate linearly between them, so more elevations mean a
    smaller error at elevations between two of them.

    Attributes
    ----------
    theta_i : int
        Incident elevations, spread uniformly over [0, π/2] (both ends
        included), ≥ 2.
    ndf : int
        Samples of the NDF and of σ along u_θ, ≥ 2.
    vndf : int
        Samples per axis of each VNDF table, ≥ 2.
    luminance : int
        Samples per axis of the luminance and RGB tables (the sample grid), ≥ 2.
    """

    theta_i: int = 32
    ndf: int = 128
    vndf: int = 128
    luminance: int = 32

    def __post_init__(self) -> None:
        limits = {"theta_i": 512, "ndf": 8192, "vndf": 2048, "luminance": 512}
        for name, upper in limits.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or not 2 <= value <= upper:
                raise ValueError(f"RGL resolution {name} must be an integer in [2, {upper}], got {value!r}")
        if self.nbytes > MAX_FILE_BYTES:
            raise ValueError(
                f"RGL resolution theta_i {self.theta_i}, vndf {self.vndf}, luminance {self.luminance} makes a file "
                f"of {self.nbytes / 2**30:.1f} GiB, more than the {MAX_FILE_BYTES / 2**30:g} GiB written at most "
                "(the VNDF tables hold theta_i × vndf² values, the RGB tables 3 × theta_i × luminance²): "
                "lower one of them"
            )

    @property
    def nbytes(self) -> int:
        """Bytes of the tables' data in a written file (float32; the header and descriptions excluded)."""
        t, n, v, g = int(self.theta_i), int(self.ndf), int(self.vndf), int(self.luminance)
        return 4 * (1 + t + 4 * n + t * v * v + 4 * t * g * g) + 1 + -(-t * g * g // 8)


def _theta_from_u(u: np.ndarray) -> np.ndarray:
    """The format's elevation coordinate: θ = u² π/2 (radians)."""
    return np.square(u) * (np.pi / 2)


def _u_from_theta(theta: np.ndarray) -> np.ndarray:
    return np.sqrt(np.clip(theta, 0.0, np.pi / 2) * (2 / np.pi))


def _azimuthal_integral(theta_a: np.ndarray, theta_b: np.ndarray) -> np.ndarray:
    """∫₀^{2π} max(0, ωa·ωb) dφ for directions of elevations θa, θb (broadcast), upper hemisphere."""
    a = np.cos(theta_a) * np.cos(theta_b)
    b = np.sin(theta_a) * np.sin(theta_b)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.clip(np.divide(a, b, out=np.ones_like(a * b), where=b > 0), -1.0, 1.0)
        phi0 = np.arccos(-ratio)
        partial = 2.0 * (a * phi0 + b * np.sqrt(np.maximum(1.0 - ratio * ratio, 0.0)))
    return np.where(a >= b, 2.0 * np.pi * a, partial)


def _trapezoid_weights(u: np.ndarray) -> np.ndarray:
    """Trapezoid weights of a uniform grid in u times the measure sin θ dθ = sin θ · π u du."""
    step = u[1] - u[0]
    weights = np.full(u.shape, step)
    weights[[0, -1]] = step / 2
    return weights * np.sin(_theta_from_u(u)) * np.pi * u


def _projection_kernel(u: np.ndarray) -> np.ndarray:
    """K[i, j] such that σ(θ_i) = Σ_j K[i, j] D(θ_j): the projected-area operator on the u grid."""
    theta = _theta_from_u(u)
    return _azimuthal_integral(theta[:, None], theta[None, :]) * _trapezoid_weights(u)[None, :]


def power_iteration_ndf(retro: npt.ArrayLike, u: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """NDF and projected area from a retro-reflection profile (Dupuy et al. 2015's power iteration).

    Parameters
    ----------
    retro : array_like, shape (n,)
        Luminance of f(ω, ω) in 1/sr at the elevations θ = u² π/2, ≥ 0.
    u : array_like, shape (n,)
        Uniform grid on [0, 1] (both ends included).

    Returns
    -------
    ndf, sigma : ndarray of float64, shape (n,)
        D(θ) in 1/sr, normalised so that ∫ D(m) cos θm dm = 1 (σ(0) = 1),
        and σ(θ) = ∫ D(m) max(0, ω·m) dm (dimensionless).
    """
    grid = np.asarray(u, dtype=np.float64)
    kernel = _projection_kernel(grid)
    theta = _theta_from_u(grid)
    profile = np.maximum(np.asarray(retro, dtype=np.float64), 0.0)
    peak = float(profile.max()) if profile.size else 0.0
    # A floor keeps the operator irreducible (a unique, positive dominant eigenvector) when f(ω, ω) vanishes.
    profile = profile + (peak * 1e-6 if peak > 0 else 1.0)
    weight = profile * np.cos(theta)
    ndf = weight.copy()
    for _ in range(_POWER_ITERATIONS):
        updated = weight * (kernel @ ndf)
        updated /= kernel[0] @ updated  # σ(0) = ∫ D cos θ dm = 1
        converged = np.allclose(updated, ndf, rtol=1e-7, atol=1e-12 * float(updated.max()))
        ndf = updated
        if converged:
            break
    return ndf, kernel @ ndf


def _sample_marginal(density: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """The continuous marginal/conditional warp of a bilinear density on the unit square.

    ``density`` (ny, nx) holds values at the vertices of a uniform grid (rows
    y, columns x); ``samples`` (N, 2) are points (x, y) of the unit square.
    Returns the warped points (N, 2): y by inverting the marginal CDF of the
    rows, then x by inverting the conditional CDF at that y, both exactly
    for the bilinear interpolant (the inversion the ``.bsdf`` readers use).
    """
    data = np.asarray(density, dtype=np.float64)
    ny, nx = data.shape
    conditional = np.zeros((ny, nx))
    conditional[:, 1:] = np.cumsum(0.5 * (data[:, 1:] + data[:, :-1]), axis=1)
    rows = conditional[:, -1]
    marginal = np.zeros(ny)
    marginal[1:] = np.cumsum(0.5 * (rows[1:] + rows[:-1]))
    scale = 1.0 / marginal[-1]
    data, conditional, rows, marginal = data * scale, conditional * scale, rows * scale, marginal * scale
    points = np.asarray(samples, dtype=np.float64)
    step = max(1, _CHUNK // nx)  # the conditional CDFs of a chunk: step × nx values
    return np.concatenate([
        _warp_chunk(data, conditional, rows, marginal, points[start : start + step])
        for start in range(0, points.shape[0], step)
    ]) if points.shape[0] else np.zeros((0, 2))


def _warp_chunk(data: np.ndarray, conditional: np.ndarray, rows: np.ndarray, marginal: np.ndarray,
                samples: np.ndarray) -> np.ndarray:
    """:func:`_sample_marginal` of some samples, given the normalised density and its CDFs."""
    ny, nx = data.shape
    s = np.clip(samples, _EPSILON32, 1.0 - _EPSILON32)
    sx, sy = s[:, 0].copy(), s[:, 1].copy()
    row = np.clip(np.searchsorted(marginal, sy, side="left") - 1, 0, ny - 2)
    sy -= marginal[row]
    r0, r1 = rows[row], rows[row + 1]
    t = _invert_linear(r0, r1, sy)
    target = sx * ((1.0 - t) * r0 + t * r1)
    cdf = (1.0 - t)[:, None] * conditional[row] + t[:, None] * conditional[row + 1]
    col = np.clip((cdf < target[:, None]).sum(axis=1) - 1, 0, nx - 2)
    target -= cdf[np.arange(col.size), col]
    c0 = (1.0 - t) * data[row, col] + t * data[row + 1, col]
    c1 = (1.0 - t) * data[row, col + 1] + t * data[row + 1, col + 1]
    x = _invert_linear(c0, c1, target)
    return np.stack([(col + np.clip(x, 0.0, 1.0)) / (nx - 1), (row + np.clip(t, 0.0, 1.0)) / (ny - 1)], axis=1)


def _invert_linear(v0: np.ndarray, v1: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """t in [0, 1] with ∫₀ᵗ ((1-τ) v0 + τ v1) dτ = mass (v0, v1 ≥ 0)."""
    total = v0 + v1
    constant = np.abs(v0 - v1) < 1e-4 * total
    with np.errstate(divide="ignore", invalid="ignore"):
        linear = (v0 - np.sqrt(np.maximum(v0 * v0 - 2.0 * mass * (v0 - v1), 0.0))) / (v0 - v1)
        flat = np.divide(2.0 * mass, total, out=np.zeros_like(mass), where=total > 0)
    return np.where(constant, flat, linear)


def _bilinear(table: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a (ny, nx) vertex table of the unit square at points (N, 2) = (x, y)."""
    ny, nx = table.shape
    x = np.clip(points[:, 0], 0.0, 1.0) * (nx - 1)
    y = np.clip(points[:, 1], 0.0, 1.0) * (ny - 1)
    x0 = np.minimum(x.astype(np.intp), nx - 2)
    y0 = np.minimum(y.astype(np.intp), ny - 2)
    fx, fy = x - x0, y - y0
    top = (1 - fx) * table[y0, x0] + fx * table[y0, x0 + 1]
    bottom = (1 - fx) * table[y0 + 1, x0] + fx * table[y0 + 1, x0 + 1]
    return (1 - fy) * top + fy * bottom


def _interpolate_profile(values: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Linear interpolation of a profile tabulated on a uniform grid of [0, 1] (as the readers do)."""
    return np.interp(u, np.linspace(0.0, 1.0, values.size), values)


def _cap_outliers(value: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Scale down RGB values whose luminance exceeds a bound set by the bulk of one θi slice.

    Where the warp lands on normals the NDF gives almost no weight (θm near π/2, or facing away from ωi),
    f cos θo · 4σ / D(m) takes values thousands of times those of the neighbouring vertices; bilinear
    interpolation would carry them into cells whose D is not small, so readers would return a spike. The
    bound is four times the 99th percentile of the slice's positive luminances (above the horizon).
    """
    lum = value @ np.asarray(LUMINANCE_WEIGHTS)
    positive = lum[up & (lum > 0)]
    if positive.size == 0:
        return value
    bound = _OUTLIER_FACTOR * float(np.percentile(positive, 99))
    scale = np.divide(bound, lum, out=np.ones_like(lum), where=lum > bound)
    return value * scale[:, None]


@dataclass(frozen=True)
class _Slice:
    """The tables of one incident elevation θi: VNDF (V, V), luminance (L, L), RGB (3, L, L), float32, and
    which of the L × L sample points reflect above the horizon."""

    vndf: np.ndarray
    luminance: np.ndarray
    rgb: np.ndarray
    above: np.ndarray


class _Tabulation:
    """The NDF, σ and incident elevations of a material, and its tables one θi at a time (:meth:`slice`).

    Memory: the material's table plus a few V × V and L × L arrays of float64 (V, L the resolution's VNDF
    and sample grid sizes); lookups and warps run in chunks of :data:`_CHUNK` points.
    """

    def __init__(self, reflectance: np.ndarray, valid: np.ndarray, res: RglResolution) -> None:
        self.values, self.mask, self.res = reflectance, valid, res
        # 1-2. NDF from the retro-reflection, and its projected area.
        u_ndf = np.linspace(0.0, 1.0, res.ndf)
        theta_ndf = np.minimum(_theta_from_u(u_ndf), _GRAZING_LIMIT)
        retro_dir = np.stack([np.sin(theta_ndf), np.zeros_like(theta_ndf), np.cos(theta_ndf)], axis=1)
        retro = self._brdf(retro_dir, retro_dir) @ np.asarray(LUMINANCE_WEIGHTS)
        self.ndf, _ = power_iteration_ndf(retro, u_ndf)
        kernel_theta = _theta_from_u(u_ndf)
        self.theta_i = np.linspace(0.0, np.pi / 2, res.theta_i)
        self.theta_eval = np.minimum(self.theta_i, _GRAZING_LIMIT)  # the grazing node: the grid's last elevation
        weights = _trapezoid_weights(u_ndf)
        self.sigma_i = _azimuthal_integral(self.theta_eval[:, None], kernel_theta[None, :]) @ (weights * self.ndf)
        self.sigma = _azimuthal_integral(kernel_theta[:, None], kernel_theta[None, :]) @ (weights * self.ndf)
        # The VNDF's unit square (x: u_θ, y: u_φ with φ relative to φi) and the sample grid.
        u_v = np.linspace(0.0, 1.0, res.vndf)
        self.theta_m = _theta_from_u(u_v)[None, :]
        self.phi_m = ((2.0 * u_v - 1.0) * np.pi)[:, None]
        self.ndf_v = _interpolate_profile(self.ndf, u_v)[None, :]
        self.jac = 2.0 * np.pi**2 * u_v[None, :] * np.sin(self.theta_m)
        grid = np.linspace(0.0, 1.0, res.luminance)
        sx, sy = np.meshgrid(grid, grid)  # [y, x]
        self.samples = np.stack([sx.ravel(), sy.ravel()], axis=1)

    def _brdf(self, wi: np.ndarray, wo: np.ndarray, mode: str = "trilinear") -> np.ndarray:
        """f(ωi, ωo) (N, 3) in 1/sr, looked up :data:`_CHUNK` direction pairs at a time."""
        out = np.empty((wo.shape[0], 3))
        for first in range(0, wo.shape[0], _CHUNK):
            part = slice(first, first + _CHUNK)
            out[part] = lookup(self.values, wi[part], wo[part], mode=mode, mask=self.mask)
        return out

    def slice(self, k: int) -> _Slice:
        """The tables of the k-th incident elevation."""
        th = float(self.theta_eval[k])
        vndf, visible = self._vndf(k, th)
        rgb, luminance, above = self._samples(k, th, vndf, visible)
        return _Slice(vndf.astype("<f4"), luminance.astype("<f4"), rgb.astype("<f4"), above)

    def _vndf(self, k: int, th: float) -> tuple[np.ndarray, np.ndarray]:
        """3. The VNDF table at θi (half visible normals, half the data's own lobe) and the visible normals."""
        theta_m, phi_m = self.theta_m, self.phi_m
        cosine = np.sin(th) * np.sin(theta_m) * np.cos(phi_m) + np.cos(th) * np.cos(theta_m)
        visible = self.ndf_v * np.maximum(cosine, 0.0) * self.jac / self.sigma_i[k]
        visible = visible / visible.sum()
        table = visible
        if _DATA_WARP_SHARE > 0:  # the data's own lobe for this θi: f cos θo in the same unit square
            wi_k = np.array([np.sin(th), 0.0, np.cos(th)])
            m_grid = np.stack(np.broadcast_arrays(np.cos(phi_m) * np.sin(theta_m), np.sin(phi_m) * np.sin(theta_m),
                                                  np.cos(theta_m)), axis=-1).reshape(-1, 3)
            dot = m_grid @ wi_k
            lum_f = np.zeros(dot.shape)
            for first in range(0, dot.size, _CHUNK):
                part = slice(first, first + _CHUNK)
                wo_k = 2.0 * dot[part, None] * m_grid[part] - wi_k
                ok = (wo_k[:, 2] > 0) & (dot[part] > 0)
                if ok.any():
                    # a sampling density only: the nearest bin suffices and costs an eighth of the trilinear lookup
                    lum_f[first + np.flatnonzero(ok)] = self._brdf(
                        np.broadcast_to(wi_k, wo_k[ok].shape), wo_k[ok], mode="nearest") @ np.asarray(LUMINANCE_WEIGHTS)
            del m_grid
            lum_f = np.maximum(lum_f, 0.0)
            if (lum_f > 0).any():  # grazing spikes (f = eval / cos θo of a tabulated file) must not own the warp
                lum_f = np.minimum(lum_f, _OUTLIER_FACTOR * float(np.percentile(lum_f[lum_f > 0], 99)))
            data = (lum_f * 4.0 * np.maximum(dot, 0.0)).reshape(visible.shape) * self.jac
            if data.sum() > 0:
                table = (1.0 - _DATA_WARP_SHARE) * visible + _DATA_WARP_SHARE * data / data.sum()
        return table, visible

    def _samples(self, k: int, th: float, vndf: np.ndarray, visible: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """4-5. RGB (3, L, L), luminance (L, L) and above-horizon flags at the warped vertices of the sample grid."""
        n = self.res.luminance
        u_m = _sample_marginal(vndf, self.samples)
        tm = _theta_from_u(u_m[:, 0])
        pm = (2.0 * u_m[:, 1] - 1.0) * np.pi
        m = np.stack([np.cos(pm) * np.sin(tm), np.sin(pm) * np.sin(tm), np.cos(tm)], axis=1)
        wi = np.array([np.sin(th), 0.0, np.cos(th)])
        wo = 2.0 * (m @ wi)[:, None] * m - wi
        up = wo[:, 2] > 0.0
        d_m = _interpolate_profile(self.ndf, u_m[:, 0])
        value = np.zeros((self.samples.shape[0], 3))
        if up.any():
            factor = wo[up, 2] * 4.0 * self.sigma_i[k] / np.maximum(d_m[up], 1e-30)
            value[up] = self._brdf(np.broadcast_to(wi, wo[up].shape), wo[up]) * factor[:, None]
        value = _cap_outliers(np.maximum(value, 0.0), up)
        rgb = value.T.reshape(3, n, n)
        # Readers sample luminance, then the VNDF table; weighting by visible / table density makes the
        # product follow the luminance of f cos θo (the table's data half only moves the grid's vertices).
        table_density, visible_density = _bilinear(vndf, u_m), _bilinear(visible, u_m)
        ratio = np.divide(visible_density, table_density, out=np.ones_like(table_density), where=table_density > 0)
        luminance = np.tensordot(np.asarray(LUMINANCE_WEIGHTS), rgb, axes=([0], [0])) * ratio.reshape(n, n)
        return rgb, luminance, up.reshape(n, n)

    def leading_fields(self, description: str) -> dict[str, np.ndarray]:
        """The fields before the per-θi tables, in file order."""
        res = self.res
        return {
            "version": np.array([1, 0], dtype="<u4"),
            "description": np.frombuffer(description.encode("utf-8"), dtype="u1").copy(),
            "phi_i": np.zeros(1, dtype="<f4"),
            "theta_i": self.theta_i.astype("<f4"),
            "sigma": np.ascontiguousarray(np.broadcast_to(self.sigma, (2, res.ndf)), dtype="<f4"),
            "ndf": np.ascontiguousarray(np.broadcast_to(self.ndf, (2, res.ndf)), dtype="<f4"),
        }

    def table_shapes(self) -> dict[str, tuple[int, ...]]:
        """Shapes of the per-θi fields, then ``jacobian`` and ``valid``, in file order."""
        t, v, n = self.res.theta_i, self.res.vndf, self.res.luminance
        return {"vndf": (1, t, v, v), "luminance": (1, t, n, n), "rgb": (1, t, 3, n, n), "jacobian": (1,),
                "valid": (-(-t * n * n // 8),)}


def rgl_fields(
    reflectance: npt.ArrayLike,
    valid: npt.ArrayLike,
    *,
    resolution: RglResolution | None = None,
    description: str = "",
) -> dict[str, np.ndarray]:
    """The fields of an isotropic RGB ``.bsdf`` file for a MERL-layout reflectance table.

    All fields in memory at once; :func:`write_rgl_bsdf` writes them a θi slice at a time instead.

    Parameters
    ----------
    reflectance : array_like, shape (3, 90, 90, 180)
        Linear RGB reflectance in 1/sr, finite.
    valid : array_like of bool, shape (3, 90, 90, 180)
        Measured entries (the others are left out of every lookup).
    resolution : RglResolution, optional
        Table sizes (the database's by default).
    description : str
        The file's description (UTF-8).

    Returns
    -------
    dict of str to ndarray
        In file order: ``version`` (uint32 (2,)), ``description`` (uint8),
        ``phi_i`` (float32 (1,), radians), ``theta_i`` (float32 (T,),
        radians), ``sigma`` and ``ndf`` (float32 (2, N)), ``vndf`` (float32
        (1, T, V, V)), ``luminance`` (float32 (1, T, L, L)), ``rgb``
        (float32 (1, T, 3, L, L)), ``jacobian`` (uint8 (1,), 1) and
        ``valid`` (uint8, the T × L × L sample points whose outgoing
        direction lies above the horizon, as packed bits).
    """
    res = resolution or RglResolution()
    tab = _Tabulation(np.asarray(reflectance, dtype=np.float64), np.asarray(valid, dtype=bool), res)
    slices = [tab.slice(k) for k in range(res.theta_i)]
    return {
        **tab.leading_fields(description),
        "vndf": np.stack([part.vndf for part in slices])[None],
        "luminance": np.stack([part.luminance for part in slices])[None],
        "rgb": np.stack([part.rgb for part in slices])[None],
        "jacobian": np.ones(1, dtype="u1"),
        "valid": np.packbits(np.stack([part.above for part in slices]).ravel()),
    }


def _tensor_file_header(specs: list[tuple[str, np.dtype, tuple[int, ...]]]) -> tuple[bytes, list[int]]:
    """The header of a tensor file holding fields (name, dtype, shape), padded to the first field's offset, and
    each field's offset (data 8-byte aligned, in the list's order)."""
    header_size = len(TENSOR_FILE_MAGIC) + 2 + 4
    header_size += sum(2 + len(name.encode("ascii")) + 2 + 1 + 8 + 8 * len(shape) for name, _, shape in specs)
    offset = -(-header_size // _ALIGNMENT) * _ALIGNMENT
    header = [TENSOR_FILE_MAGIC, struct.pack("<BBI", 1, 0, len(specs))]
    offsets = []
    for name, dtype, shape in specs:
        code = _DTYPE_CODES.get(dtype.newbyteorder("<") if dtype.byteorder == ">" else dtype)
        if code is None:
            raise ValueError(f"tensor-file field {name!r}: unsupported dtype {dtype}")
        encoded = name.encode("ascii")
        header.append(struct.pack("<H", len(encoded)) + encoded + struct.pack("<HBQ", len(shape), code, offset))
        header.append(struct.pack(f"<{len(shape)}Q", *shape))
        offsets.append(offset)
        size = dtype.itemsize * math.prod(shape)
        offset += size + (-size % _ALIGNMENT)
    head = b"".join(header)
    return head + b"\x00" * (offsets[0] - len(head) if offsets else -len(head) % _ALIGNMENT), offsets


def tensor_file_bytes(fields: Mapping[str, np.ndarray]) -> bytes:
    """Serialise fields as a Mitsuba tensor file (format 1.0, little-endian, data 8-byte aligned).

    Parameters
    ----------
    fields : mapping of str to ndarray
        Name → array of dtype uint8, uint32 or float32, written in the mapping's order.

    Returns
    -------
    bytes
    """
    arrays = {name: np.ascontiguousarray(array) for name, array in fields.items()}
    head, _ = _tensor_file_header([(name, value.dtype, value.shape) for name, value in arrays.items()])
    body = bytearray()
    for value in arrays.values():
        body += value.astype(value.dtype.newbyteorder("<"), copy=False).tobytes()
        body += b"\x00" * (-len(body) % _ALIGNMENT)
    return head + bytes(body)


def _write_tensor_file(path: Path, tab: _Tabulation, description: str) -> None:
    """Write the material's tensor file to ``path``, one θi slice at a time (each table written in place)."""
    leading = tab.leading_fields(description)
    shapes = tab.table_shapes()
    f32, u8 = np.dtype("<f4"), np.dtype("u1")
    specs = [(name, value.dtype, value.shape) for name, value in leading.items()]
    specs += [(name, u8 if name in ("jacobian", "valid") else f32, shape) for name, shape in shapes.items()]
    head, offsets = _tensor_file_header(specs)
    at = dict(zip([name for name, _, _ in specs], offsets, strict=True))
    n_theta = tab.res.theta_i
    above = np.zeros((n_theta, tab.res.luminance, tab.res.luminance), dtype=bool)
    with open(path, "wb") as stream:
        stream.write(head)
        for name, value in leading.items():
            stream.seek(at[name])
            stream.write(value.tobytes())
        for k in range(n_theta):
            part = tab.slice(k)
            for name, table in (("vndf", part.vndf), ("luminance", part.luminance), ("rgb", part.rgb)):
                stream.seek(at[name] + k * table.nbytes)
                stream.write(table.tobytes())
            above[k] = part.above
        stream.seek(at["jacobian"])
        stream.write(b"\x01")
        stream.seek(at["valid"])
        valid = np.packbits(above.ravel()).tobytes()
        stream.write(valid + b"\x00" * (-len(valid) % _ALIGNMENT))


def _checked_reflectance(path: Path, table: npt.ArrayLike, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Reflectance (1/sr) and validity of a stored-unit table; RglWriteError naming ``path`` if unusable."""
    stored = np.asarray(table)
    if stored.shape != TABLE_SHAPE:
        raise RglWriteError(path, f"material {name!r}: table shape {stored.shape}, expected {TABLE_SHAPE}")
    if not np.issubdtype(stored.dtype, np.floating):
        raise RglWriteError(path, f"material {name!r}: table dtype {stored.dtype}, expected floating point")
    stored = stored.astype(np.float64)
    if not np.isfinite(stored).all():
        raise RglWriteError(path, f"material {name!r}: the table holds NaN or infinite values")
    valid = (stored >= 0.0) & horizon_mask()[None]
    if not valid.any():
        raise RglWriteError(path, f"material {name!r}: no measured entry above the horizon: nothing to write")
    reflectance = np.where(valid, reflectance_from_stored(np.maximum(stored, 0.0)), 0.0)
    if not (reflectance > 0).any():
        raise RglWriteError(path, f"material {name!r}: all black (no positive reflectance): "
                            "the format's NDF and sampling tables are undefined")
    return reflectance, valid


def write_rgl_bsdf(
    path: str | os.PathLike[str],
    table: npt.ArrayLike,
    *,
    name: str = "",
    description: str | None = None,
    resolution: RglResolution | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a MERL-layout table as an isotropic RGB RGL ``.bsdf`` file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The output file (any suffix; ``.bsdf`` by convention).
    table : array_like, shape (3, 90, 90, 180)
        Stored MERL units (reflectance / MERL colour scale); negative entries
        are unmeasured (MERL's convention) and left out.
    name : str
        Material name, for messages and the default description.
    description : str, optional
        The file's ``description`` field; ``"NAME (brdfcodec export)"`` when absent or empty (Mitsuba's
        ``measured`` plugin refuses an empty one).
    resolution : RglResolution, optional
        Table sizes (:class:`RglResolution`'s defaults when absent).
    overwrite : bool, default False
        Whether an existing file may be replaced.

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    RglWriteError
        The table is malformed, holds NaN or infinite values, has no measured
        entry, or is all black; nothing is written.
    FileExistsError, IsADirectoryError, FileNotFoundError
        As :func:`brdfcodec.io.atomic.check_output_path`.
    """
    target = check_output_path(path, overwrite=overwrite)
    reflectance, valid = _checked_reflectance(target, table, name)
    text = description or f"{name or target.stem} (brdfcodec export)"  # readers refuse an empty description
    tab = _Tabulation(reflectance, valid, resolution or RglResolution())
    with atomic_output(target, overwrite=overwrite) as tmp:
        _write_tensor_file(tmp, tab, text)
    return target
