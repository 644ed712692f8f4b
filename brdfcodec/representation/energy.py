"""Directional albedo of a MERL-layout table, and the energy bound (``spec/conventions.md`` §9).

The directional albedo of a BRDF ρ lit from direction ωi is

.. math::

    a(ω_i) = \\int_{H^2} ρ(ω_i, ω_o) \\cos θ_o \\, dω_o ,

the fraction of the light arriving from ωi that leaves the surface; energy
conservation requires ``a ≤ 1`` for every ωi and colour channel. On the MERL
grid it is evaluated by quadrature over the half vector (``ωo`` is ``ωi``
reflected about ``ωh``, ``dωo = 4 cos θd dωh``). Each direction reads the
table's bin as a MERL lookup does (entries below the horizon or unmeasured
count as 0), so the integral is a weighted sum of bins whose weights depend
on the incident direction only: they are computed once, by a fine midpoint
rule aligned with the θh bins (:func:`_quadrature`), and match a
stratified reference of 10⁵–10⁶ directions to 0.1 % on sharp lobes (a
chrome-like material, a one-bin spike; ``tests/test_energy_quadrature.py``).
(The earlier rule, one node per θh bin at its lower edge, gave the
first bin no weight and under-counted mirror-like lobes by several percent.)

:func:`energy_bound_scale` is the factor that brings a table's largest
directional albedo (over the incident elevations of :data:`ALBEDO_THETA_I_DEG`
and the three channels) down to 1: ``min(1, 1 / max a)``. The decoder
multiplies an edited material by it (``spec/bvae-format.md`` §6.3): a uniform
factor keeps the material's colour and the shape of its lobes and makes it
conserve energy. :func:`directional_albedo_mapped` and
:func:`energy_bound_scale_mapped` compute the same from the 21 kept slices in
the mapped domain, reading each φd bin as the decoder's interpolation makes it
(``spec/conventions.md`` §7); :func:`scale_mapped` applies a factor there.

Examples
--------
A Lambertian table of albedo 0.5 has directional albedo 0.5 at every angle:

>>> import numpy as np
>>> from brdfcodec.representation import stored_from_reflectance
>>> table = stored_from_reflectance(np.full((3, 90, 90, 180), 0.5 / np.pi))
>>> albedo = directional_albedo(table)
>>> albedo.shape, bool(np.allclose(albedo, 0.5, atol=0.01))
((13, 3), True)
>>> float(energy_bound_scale(table))
1.0
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import EPSILON, MAPPED_MAX, N_CHANNELS, N_KEPT_SLICES, N_PHI_D, N_THETA_D, N_THETA_H
from brdfcodec.representation.coords import half_diff_from_directions, phi_d_index, theta_d_index
from brdfcodec.representation.layout import interpolation_plan
from brdfcodec.representation.mapping import LOG_RANGE
from brdfcodec.representation.mask import horizon_mask
from brdfcodec.representation.units import reflectance_from_stored

__all__ = [
    "ALBEDO_THETA_I_DEG",
    "bound_scales",
    "directional_albedo",
    "directional_albedo_mapped",
    "energy_bound_scale",
    "energy_bound_scale_mapped",
    "scale_mapped",
]

#: Incident elevations (degrees) at which the bound is evaluated: 0° to 80° in steps of 10°, then 82.5–87.5°.
#: Beyond 87.5° the MERL grid's θd bins are too coarse for a reliable integral.
ALBEDO_THETA_I_DEG = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 75.0, 80.0, 82.5, 85.0, 87.5)

#: Sub-rows per θh bin and φh columns (a multiple of 360, so that columns sit between whole degrees) of the
#: quadrature: enough for sharp lobes to 0.1 % (``tests/test_energy_quadrature.py``).
_SUB_ROWS = 4
_N_PHI_H = 1440


def _nodes_for(theta_i: float) -> tuple[np.ndarray, np.ndarray]:
    """One incident elevation's quadrature, summed per bin: flat bin keys ``(h·90 + d)·180 + p`` and weights."""
    # θh bin i spans u = sqrt(θh / (π/2)) in [i/90, (i+1)/90) (spec/conventions.md §3): sub-rows are equal
    # parts of each bin in u, nodes at their midpoints, and the solid angle's factor ∫ sin θh dθh is taken
    # exactly over each sub-row (a midpoint rule on it under-counts the first bins, where it grows as u³).
    edges = (np.pi / 2) * (np.arange(N_THETA_H * _SUB_ROWS + 1) / (N_THETA_H * _SUB_ROWS)) ** 2
    u = (np.arange(N_THETA_H * _SUB_ROWS) + 0.5) / (N_THETA_H * _SUB_ROWS)
    theta_h = (np.pi / 2) * u**2
    w_h = np.cos(edges[:-1]) - np.cos(edges[1:])
    phi_h = (np.arange(_N_PHI_H) + 0.5) * (2 * np.pi / _N_PHI_H)
    th, ph = np.meshgrid(theta_h, phi_h, indexing="ij")
    wi = np.array([np.sin(theta_i), 0.0, np.cos(theta_i)])
    half = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    cos_d = half @ wi
    wo = 2.0 * cos_d[..., None] * half - wi
    _, theta_d, phi_d, _ = half_diff_from_directions(np.broadcast_to(wi, wo.shape), wo)
    h = np.broadcast_to((np.arange(len(u)) // _SUB_ROWS)[:, None], th.shape)
    d, p = theta_d_index(theta_d), phi_d_index(phi_d)
    keep = (cos_d > 0) & (wo[..., 2] > 0)
    keep &= horizon_mask()[h, d, p]
    weight = (wo[..., 2] * 4.0 * cos_d * w_h[:, None] * (2 * np.pi / _N_PHI_H))[keep]
    key = (h[keep] * N_THETA_D + d[keep]) * N_PHI_D + p[keep]
    bins, where = np.unique(key, return_inverse=True)
    return bins, np.bincount(where, weights=weight, minlength=len(bins))


#: The quadrature as shipped (``brdfcodec/data/energy-quadrature.npz``): :func:`_computed_quadrature`'s arrays,
#: stored exactly (float64 weights), so that a process does not spend seconds building them before its first
#: bounded decode. ``tests/test_energy_quadrature.py`` recomputes them and compares (slow); ``python -m
#: brdfcodec.representation.energy`` writes the file anew after a change of the rule.
QUADRATURE_FILE = "data/energy-quadrature.npz"


def _shipped_quadrature() -> tuple[np.ndarray, ...] | None:
    """The shipped quadrature's arrays (h, d, p, weight, row), or None where the file is absent or not as expected."""
    from importlib import resources

    try:
        with resources.files("brdfcodec").joinpath(QUADRATURE_FILE).open("rb") as handle:
            with np.load(handle, allow_pickle=False) as stored:
                arrays = tuple(np.asarray(stored[key]) for key in ("h", "d", "p", "weight", "row"))
                rule = stored["rule"].tolist()
    except (OSError, KeyError, ValueError):
        return None
    if rule != [_SUB_ROWS, _N_PHI_H, *ALBEDO_THETA_I_DEG] or len({len(a) for a in arrays}) != 1:
        return None
    h, d, p, weight, row = arrays
    return (h.astype(np.intp), d.astype(np.intp), p.astype(np.intp), weight.astype(np.float64), row.astype(np.intp))


def write_quadrature(path: str) -> None:
    """Write :func:`_computed_quadrature`'s arrays to ``path`` (an ``.npz``), as the package ships them."""
    h, d, p, weight, row = _computed_quadrature()
    rule = np.asarray([_SUB_ROWS, _N_PHI_H, *ALBEDO_THETA_I_DEG], dtype=np.float64)
    np.savez_compressed(path, h=h.astype(np.uint8), d=d.astype(np.uint8), p=p.astype(np.uint8), weight=weight,
                        row=row.astype(np.uint8), rule=rule)


@functools.cache
def _quadrature() -> tuple[np.ndarray, ...]:
    """The quadrature (read-only arrays of equal length n, sorted by row): the shipped file, else computed."""
    out = _shipped_quadrature() or _computed_quadrature()
    for array in out:
        array.setflags(write=False)
    return out


def _computed_quadrature() -> tuple[np.ndarray, ...]:
    """The quadrature, computed (a few seconds of CPU; arrays of equal length n, sorted by row).

    The integrand is piecewise constant on the MERL bins (each direction reads its bin, as a lookup does), so
    the integral is exactly ``Σ ρ_bin · W_bin`` with ``W_bin`` the cosine-weighted solid angle of the outgoing
    directions that read the bin. ``W`` is computed once per incident elevation by a fine midpoint rule in the
    half vector (``ωo`` is ``ωi`` reflected about ``ωh``, ``dωo = 4 cos θd dωh``): :data:`_SUB_ROWS` sub-rows in
    every θh bin (aligned with the bins, so the sharp θh bins near the peak are never straddled) and
    :data:`_N_PHI_H` φh columns, summed per bin. A table's albedo then reads each bin once.

    Returns
    -------
    h, d, p : ndarray of intp
        θh, θd and φd bins (bins below the horizon are left out).
    weight : ndarray of float64
        ``W`` of the bin for that incident elevation (sr, cosine-weighted).
    row : ndarray of intp
        Which entry of :data:`ALBEDO_THETA_I_DEG` the bin integrates for.
    """
    keys, weights, rows = [], [], []
    for row, theta_i in enumerate(np.radians(np.asarray(ALBEDO_THETA_I_DEG))):
        key, weight = _nodes_for(float(theta_i))
        keys.append(key)
        weights.append(weight)
        rows.append(np.full(len(key), row, dtype=np.intp))
    key = np.concatenate(keys)
    h, rest = np.divmod(key, N_THETA_D * N_PHI_D)
    d, p = np.divmod(rest, N_PHI_D)
    return tuple(np.ascontiguousarray(a) for a in (h, d, p, np.concatenate(weights), np.concatenate(rows)))


@functools.cache
def _row_starts() -> np.ndarray:
    """Where each incident elevation's bins begin in the (row-sorted) quadrature."""
    row = _quadrature()[4]
    starts = np.searchsorted(row, np.arange(len(ALBEDO_THETA_I_DEG)))
    starts.setflags(write=False)
    return starts


@functools.cache
def _flat_bins() -> np.ndarray:
    """The quadrature's bins as flat indices into one channel of a (90, 90, 180) table."""
    h, d, p, _, _ = _quadrature()
    flat = (h * N_THETA_D + d) * N_PHI_D + p
    flat.setflags(write=False)
    return flat


def _sum_rows(values: np.ndarray) -> np.ndarray:
    """Bin values (N, 3, n) summed per θi row with the quadrature weights: (N, 13, 3)."""
    weight = _quadrature()[3]
    out = np.add.reduceat(values * weight, _row_starts(), axis=-1)  # rows are contiguous and none is empty
    return np.moveaxis(out, 1, 2)


def directional_albedo(table: npt.ArrayLike) -> np.ndarray:
    """Directional albedo per incident elevation and channel, from a full table.

    Parameters
    ----------
    table : array_like, shape (3, 90, 90, 180) or (N, 3, 90, 90, 180)
        Stored MERL values (``spec/conventions.md`` §2); negative entries
        (unmeasured) and non-finite ones count as 0, as do bins below the horizon.

    Returns
    -------
    ndarray of float64, shape (13, 3) or (N, 13, 3)
        ``a(θi)`` at :data:`ALBEDO_THETA_I_DEG` (dimensionless), per channel.
    """
    values = np.asarray(table)
    single = values.ndim == 4
    stack = values[None] if single else values
    if stack.shape[1:] != (N_CHANNELS, N_THETA_H, N_THETA_D, N_PHI_D):
        raise ValueError(f"expected tables of shape (3, 90, 90, 180), got {values.shape}")
    flat = stack.reshape(*stack.shape[:2], -1)
    picked = np.take(flat, _flat_bins(), axis=-1).astype(np.float64)  # (N, 3, n)
    picked = np.where(np.isfinite(picked) & (picked > 0), picked, 0.0)
    out = _sum_rows(reflectance_from_stored(picked, channel_axis=1))
    return out[0] if single else out


def directional_albedo_mapped(mapped: npt.ArrayLike) -> np.ndarray:
    """Directional albedo from the 21 kept slices in the mapped domain (network layout).

    Each node reads its φd bin as the decoder makes it: linear interpolation
    of the clamped mapped values between the neighbouring kept slices, then the
    inverse mapping (``spec/conventions.md`` §4, §7). Equal, up to rounding, to
    :func:`directional_albedo` of the decoded table.

    Parameters
    ----------
    mapped : array_like, shape (63, 90, 90) or (N, 63, 90, 90)
        Mapped kept slices, channel-major (``spec/conventions.md`` §6).

    Returns
    -------
    ndarray of float64, shape (13, 3) or (N, 13, 3)
    """
    values = np.asarray(mapped)
    single = values.ndim == 3
    stack = values[None] if single else values
    if stack.shape[1:] != (N_CHANNELS * N_KEPT_SLICES, N_THETA_H, N_THETA_D):
        raise ValueError(f"expected mapped slices of shape (63, 90, 90), got {values.shape}")
    blocks = stack.reshape(stack.shape[0], N_CHANNELS, N_KEPT_SLICES, N_THETA_H, N_THETA_D)
    h, d, p, _, _ = _quadrature()
    left, right, t = interpolation_plan()
    low = np.clip(np.nan_to_num(blocks[:, :, left[p], h, d].astype(np.float64)), 0.0, MAPPED_MAX)
    high = np.clip(np.nan_to_num(blocks[:, :, right[p], h, d].astype(np.float64)), 0.0, MAPPED_MAX)
    value = (1.0 - t[p]) * low + t[p] * high
    out = _sum_rows(EPSILON * np.expm1(value * LOG_RANGE))
    return out[0] if single else out


def bound_scales(largest: npt.ArrayLike) -> np.ndarray:
    """The energy bound's factors ``min(1, 1 / a)`` of largest directional albedos ``a`` (any shape)."""
    values = np.asarray(largest, dtype=np.float64)
    return np.where(values > 1.0, 1.0 / np.maximum(values, 1.0), 1.0)


def energy_bound_scale(table: npt.ArrayLike) -> float:
    """The factor ``min(1, 1 / max a)`` that makes a full table conserve energy.

    Parameters
    ----------
    table : array_like, shape (3, 90, 90, 180)
        Stored MERL values.

    Returns
    -------
    float
        In (0, 1]; 1 when the table's largest directional albedo is at most 1.
    """
    return float(bound_scales(np.max(directional_albedo(table))))


def energy_bound_scale_mapped(mapped: npt.ArrayLike) -> float:
    """:func:`energy_bound_scale` of the table that mapped kept slices (63, 90, 90) decode to."""
    return float(bound_scales(np.max(directional_albedo_mapped(mapped))))


def scale_mapped(mapped: npt.ArrayLike, scale: float) -> np.ndarray:
    """Mapped values of the reflectance multiplied by ``scale``: ``log1p(s · expm1(m · L)) / L``.

    Parameters
    ----------
    mapped : array_like
        Mapped values (clamped to the mapped domain here).
    scale : float
        Factor on reflectance, in (0, 1].

    Returns
    -------
    ndarray
        Same shape; float32 for float32 input, else float64. ``scale == 1`` returns the clamped input.
    """
    values = np.clip(np.nan_to_num(np.asarray(mapped)), 0.0, MAPPED_MAX)
    if scale == 1.0:
        return values
    dtype = values.dtype if values.dtype == np.float32 else np.float64
    out = np.log1p(scale * np.expm1(values.astype(np.float64) * LOG_RANGE)) / LOG_RANGE
    return out.astype(dtype)


if __name__ == "__main__":  # python -m brdfcodec.representation.energy [PATH]: write the shipped quadrature
    import sys
    from pathlib import Path

    target = sys.argv[1] if len(sys.argv) > 1 else str(Path(__file__).resolve().parents[1] / QUADRATURE_FILE)
    write_quadrature(target)
    print(f"wrote {target}")
