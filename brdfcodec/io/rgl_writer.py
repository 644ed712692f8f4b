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


def rgl_fields(
    reflectance: npt.ArrayLike,
    valid: npt.ArrayLike,
    *,
    resolution: RglResolution | None = None,
    description: str = "",
) -> dict[str, np.ndarray]:
    """The fields of an isotropic RGB ``.bsdf`` file for a MERL-layout reflectance table.

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
    values = np.asarray(reflectance, dtype=np.float64)
    mask = np.asarray(valid, dtype=bool)

    def brdf(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        return lookup(values, wi, wo, mode="trilinear", mask=mask)

    # 1-2. NDF from the retro-reflection, and its projected area.
    u_ndf = np.linspace(0.0, 1.0, res.ndf)
    theta_ndf = np.minimum(_theta_from_u(u_ndf), _GRAZING_LIMIT)
    retro_dir = np.stack([np.sin(theta_ndf), np.zeros_like(theta_ndf), np.cos(theta_ndf)], axis=1)
    retro = brdf(retro_dir, retro_dir) @ np.asarray(LUMINANCE_WEIGHTS)
    ndf, _ = power_iteration_ndf(retro, u_ndf)
    kernel_theta = _theta_from_u(u_ndf)
    theta_i = np.linspace(0.0, np.pi / 2, res.theta_i)
    theta_eval = np.minimum(theta_i, _GRAZING_LIMIT)  # the grazing node: the last elevation the grid holds
    weights = _trapezoid_weights(u_ndf)
    sigma_i = _azimuthal_integral(theta_eval[:, None], kernel_theta[None, :]) @ (weights * ndf)
    sigma = _azimuthal_integral(kernel_theta[:, None], kernel_theta[None, :]) @ (weights * ndf)

    # 3. VNDF per incident elevation, in the unit square (x: u_θ, y: u_φ with φ relative to φi).
    u_v = np.linspace(0.0, 1.0, res.vndf)
    theta_m = _theta_from_u(u_v)[None, :]
    phi_m = ((2.0 * u_v - 1.0) * np.pi)[:, None]
    ndf_v = _interpolate_profile(ndf, u_v)[None, :]
    jac = 2.0 * np.pi**2 * u_v[None, :] * np.sin(theta_m)
    vndf = np.empty((res.theta_i, res.vndf, res.vndf))
    visible = np.empty_like(vndf)  # the NDF's visible normals alone, for the luminance tables
    m_grid = np.stack(np.broadcast_arrays(np.cos(phi_m) * np.sin(theta_m), np.sin(phi_m) * np.sin(theta_m),
                                          np.cos(theta_m)), axis=-1).reshape(-1, 3)
    for k, th in enumerate(theta_eval):
        cosine = np.sin(th) * np.sin(theta_m) * np.cos(phi_m) + np.cos(th) * np.cos(theta_m)
        slice_ = ndf_v * np.maximum(cosine, 0.0) * jac / sigma_i[k]
        slice_ = slice_ / slice_.sum()
        visible[k] = slice_
        if _DATA_WARP_SHARE > 0:  # the data's own lobe for this θi: f cos θo in the same unit square
            wi_k = np.array([np.sin(th), 0.0, np.cos(th)])
            dot = m_grid @ wi_k
            wo_k = 2.0 * dot[:, None] * m_grid - wi_k
            ok = (wo_k[:, 2] > 0) & (dot > 0)
            lum_f = np.zeros(dot.shape)
            if ok.any():
                # a sampling density only: the nearest bin suffices and costs an eighth of the trilinear lookup
                lum_f[ok] = lookup(values, np.broadcast_to(wi_k, wo_k[ok].shape), wo_k[ok], mode="nearest",
                                   mask=mask) @ np.asarray(LUMINANCE_WEIGHTS)
            lum_f = np.maximum(lum_f, 0.0)
            if (lum_f > 0).any():  # grazing spikes (f = eval / cos θo of a tabulated file) must not own the warp
                lum_f = np.minimum(lum_f, _OUTLIER_FACTOR * float(np.percentile(lum_f[lum_f > 0], 99)))
            data = lum_f * 4.0 * np.maximum(dot, 0.0)
            data = data.reshape(slice_.shape) * jac
            if data.sum() > 0:
                slice_ = (1.0 - _DATA_WARP_SHARE) * slice_ + _DATA_WARP_SHARE * data / data.sum()
        vndf[k] = slice_

    # 4-5. RGB and luminance at the warped vertices of the sample grid.
    n = res.luminance
    grid = np.linspace(0.0, 1.0, n)
    sx, sy = np.meshgrid(grid, grid)  # [y, x]
    samples = np.stack([sx.ravel(), sy.ravel()], axis=1)
    rgb = np.zeros((res.theta_i, 3, n, n))
    weight = np.ones((res.theta_i, n, n))
    above = np.zeros((res.theta_i, n, n), dtype=bool)
    for k, th in enumerate(theta_eval):
        u_m = _sample_marginal(vndf[k], samples)
        tm = _theta_from_u(u_m[:, 0])
        pm = (2.0 * u_m[:, 1] - 1.0) * np.pi
        m = np.stack([np.cos(pm) * np.sin(tm), np.sin(pm) * np.sin(tm), np.cos(tm)], axis=1)
        wi = np.array([np.sin(th), 0.0, np.cos(th)])
        wo = 2.0 * (m @ wi)[:, None] * m - wi
        up = wo[:, 2] > 0.0
        d_m = _interpolate_profile(ndf, u_m[:, 0])
        value = np.zeros((samples.shape[0], 3))
        if up.any():
            factor = wo[up, 2] * 4.0 * sigma_i[k] / np.maximum(d_m[up], 1e-30)
            value[up] = brdf(np.broadcast_to(wi, wo[up].shape), wo[up]) * factor[:, None]
        value = _cap_outliers(np.maximum(value, 0.0), up)
        rgb[k] = value.T.reshape(3, n, n)
        above[k] = up.reshape(n, n)
        # Readers sample luminance, then the VNDF table; weighting by visible / table density makes the
        # product follow the luminance of f cos θo (the table's data half only moves the grid's vertices).
        table_density, visible_density = _bilinear(vndf[k], u_m), _bilinear(visible[k], u_m)
        ratio = np.divide(visible_density, table_density, out=np.ones_like(table_density), where=table_density > 0)
        weight[k] = ratio.reshape(n, n)
    luminance = np.tensordot(np.asarray(LUMINANCE_WEIGHTS), rgb, axes=([0], [1])) * weight

    sigma2 = np.broadcast_to(sigma, (2, res.ndf))
    ndf2 = np.broadcast_to(ndf, (2, res.ndf))
    return {
        "version": np.array([1, 0], dtype="<u4"),
        "description": np.frombuffer(description.encode("utf-8"), dtype="u1").copy(),
        "phi_i": np.zeros(1, dtype="<f4"),
        "theta_i": theta_i.astype("<f4"),
        "sigma": np.ascontiguousarray(sigma2, dtype="<f4"),
        "ndf": np.ascontiguousarray(ndf2, dtype="<f4"),
        "vndf": vndf[None].astype("<f4"),
        "luminance": luminance[None].astype("<f4"),
        "rgb": rgb[None].astype("<f4"),
        "jacobian": np.ones(1, dtype="u1"),
        "valid": np.packbits(above.ravel()),
    }


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
    arrays = []
    for name, array in fields.items():
        value = np.ascontiguousarray(array)
        code = _DTYPE_CODES.get(value.dtype.newbyteorder("<") if value.dtype.byteorder == ">" else value.dtype)
        if code is None:
            raise ValueError(f"tensor-file field {name!r}: unsupported dtype {value.dtype}")
        arrays.append((name.encode("ascii"), code, value.astype(value.dtype.newbyteorder("<"), copy=False)))
    header_size = len(TENSOR_FILE_MAGIC) + 2 + 4
    header_size += sum(2 + len(name) + 2 + 1 + 8 + 8 * value.ndim for name, _, value in arrays)
    offset = -(-header_size // _ALIGNMENT) * _ALIGNMENT
    header = [TENSOR_FILE_MAGIC, struct.pack("<BBI", 1, 0, len(arrays))]
    body = bytearray()
    for name, code, value in arrays:
        header.append(struct.pack("<H", len(name)) + name + struct.pack("<HBQ", value.ndim, code, offset + len(body)))
        header.append(struct.pack(f"<{value.ndim}Q", *value.shape))
        body += value.tobytes()
        body += b"\x00" * (-len(body) % _ALIGNMENT)
    head = b"".join(header)
    return head + b"\x00" * (offset - len(head)) + bytes(body)


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
        The file's ``description`` field; ``"NAME (brdfcodec export)"`` by default.
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
    text = description if description is not None else f"{name or target.stem} (brdfcodec export)"
    data = tensor_file_bytes(rgl_fields(reflectance, valid, resolution=resolution, description=text))
    with atomic_output(target, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)
    return target
