"""Mitsuba 3 plug-in: BSDFs that read a ``.bvae`` material or a MERL file (optional extra ``brdfcodec[mitsuba]``).

Usage::

    from brdfcodec.render import mitsuba_bsdf
    from brdfcodec.runtime import mitsuba as mitsuba_runtime
    mitsuba_runtime.set_variant("llvm_ad_rgb")     # finds libLLVM; falls back to scalar_rgb with a warning
    mitsuba_bsdf.register()                        # adds "bvae" and "merl" to the current variant
    bsdf = {"type": "bvae", "filename": "lib.bvae", "material": "gold"}
    original = {"type": "merl", "filename": "gold.binary"}   # or "bvae" with a .binary filename

Properties: ``filename`` (``.bvae`` or MERL ``.binary``, told apart by the
file's first bytes; relative paths are resolved by Mitsuba's file resolver,
i.e. against the scene's folder), ``material`` (for a library of several),
``precision`` (``"float32"``, default, or ``"float16"``: half the memory),
``sampling`` (``"tabulated"``, default, ``"theta_h"`` or ``"cosine"``) and
``cosine_fraction`` (share of cosine-weighted samples in the mixture;
default :data:`WARP_COSINE_SHARE` for ``"tabulated"``, from the material for
``"theta_h"``: :func:`~brdfcodec.render.mitsuba_tables.cosine_share`).

The material is decoded once per process for every BSDF that names the same
file, material and precision (:func:`brdfcodec.render.mitsuba_tables.material_tables`),
so shapes of a scene share one table. Evaluation is the lookup of
``spec/conventions.md`` §3 (θh's square-root bins, φd folded by reciprocity,
0 at or below the horizon; ``"lookup"``: ``"nearest"``, default, or
``"trilinear"``, both as :func:`brdfcodec.representation.lookup.lookup`), in the precision of
the variant (float32 in the ``*_rgb`` variants, so a direction pair within
float32 rounding of a bin edge may land in the neighbouring bin).

* ``llvm_*`` / ``cuda_*`` variants (:class:`VectorBvaeBSDF`, built per variant):
  the table is one Dr.Jit array gathered for whole wavefronts. Sampling
  (``"tabulated"``) is that of Mitsuba's ``measured`` BSDF on the material's
  RGL export: a point warped by the luminance density, then by the visible-normal
  (VNDF) density to a microfacet normal, ωo the reflection of ωi about it
  (:func:`~brdfcodec.render.mitsuba_tables.sampling_warps`, Mitsuba's
  ``MarginalContinuous2D1`` over the incident elevation), mixed with a small
  share of cosine-weighted directions; ``pdf`` inverts the same warps, so it is
  the density ``sample`` draws from. ``"theta_h"``: half vectors drawn from the
  material's tabulated θh marginal (:func:`~brdfcodec.render.mitsuba_tables.theta_h_marginal`,
  φh uniform) mixed with cosine-weighted directions. ``traverse``
  exposes the table (``reflectance``, 1/sr ÷ ``scale``, channels last).
* ``scalar_*`` variants (:class:`ScalarBvaeBSDF`): one Python call per sample,
  cosine-weighted sampling; slow but simple, kept as the reference.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from brdfcodec.conventions import BIN_TOLERANCE, HORIZON_COS_MIN, N_PHI_D, N_THETA_D, N_THETA_H
from brdfcodec.render.mitsuba_tables import MaterialTables, cosine_share, material_tables, theta_h_edges

__all__ = ["MERL_PLUGIN_NAME", "PLUGIN_NAME", "bsdf_class", "material_of", "nearest_value", "register"]

PLUGIN_NAME = "bvae"
MERL_PLUGIN_NAME = "merl"
#: Share of cosine-weighted directions mixed with the warps' (``sampling`` "tabulated"): it bounds the sample
#: weights (by π f / share) where the warps' tables, coarser than the material's, give a low density. Small, because
#: every cosine sample is one the lobe misses: chrome of the example library under a sky with a sun has 1.8× the
#: relative MSE of Mitsuba's ``measured`` at a share of 0.1, 1.4× at 0.02 (benchmarks/test_bench_sampling.py).
WARP_COSINE_SHARE = 0.01


def _mitsuba() -> Any:
    try:
        import mitsuba as mi
    except ImportError as error:  # pragma: no cover - optional extra
        raise ImportError("the Mitsuba plug-in needs Mitsuba 3: pip install 'brdfcodec[mitsuba]'") from error
    if mi.variant() is None:
        from brdfcodec.runtime.mitsuba import set_variant

        set_variant()
    return mi


def nearest_value(table: np.ndarray, wi: tuple[float, float, float], wo: tuple[float, float, float]) -> np.ndarray:
    """Nearest-bin lookup of one direction pair with scalar arithmetic (spec/conventions.md §3).

    Same bins as :func:`brdfcodec.representation.lookup.lookup` in ``"nearest"`` mode, much
    faster for a single pair, since it skips numpy's per-call overhead (Mitsuba's scalar variants
    call the BSDF once per sample). ``table`` is physical reflectance, shape (3, 90, 90, 180),
    with invalid entries 0 (or negative: they give 0).
    """
    n_i = math.sqrt(wi[0] * wi[0] + wi[1] * wi[1] + wi[2] * wi[2])
    n_o = math.sqrt(wo[0] * wo[0] + wo[1] * wo[1] + wo[2] * wo[2])
    if n_i == 0.0 or n_o == 0.0 or wi[2] / n_i <= HORIZON_COS_MIN or wo[2] / n_o <= HORIZON_COS_MIN:
        return np.zeros(3)
    x, y, z = wi[0] / n_i, wi[1] / n_i, wi[2] / n_i
    hx, hy, hz = x + wo[0] / n_o, y + wo[1] / n_o, z + wo[2] / n_o
    theta_h = math.atan2(math.hypot(hx, hy), hz)
    phi_h = math.atan2(hy, hx)
    c, s = math.cos(-phi_h), math.sin(-phi_h)
    x, y = c * x - s * y, s * x + c * y
    c, s = math.cos(-theta_h), math.sin(-theta_h)
    x, z = c * x + s * z, -s * x + c * z
    theta_d = math.atan2(math.hypot(x, y), z)
    phi_d = math.atan2(y, x) % math.pi
    if phi_d >= math.pi:
        phi_d = 0.0
    i = min(max(int(math.floor(N_THETA_H * math.sqrt(theta_h / (math.pi / 2)) + BIN_TOLERANCE)), 0), N_THETA_H - 1)
    j = min(max(int(math.floor(N_THETA_D * theta_d / (math.pi / 2) + BIN_TOLERANCE)), 0), N_THETA_D - 1)
    k = min(max(int(math.floor(N_PHI_D * phi_d / math.pi + BIN_TOLERANCE)), 0), N_PHI_D - 1)
    return np.maximum(table[:, i, j, k], 0.0)


def _source_properties(props: Any, default_kind: str) -> dict[str, Any]:
    """filename (resolved), material, kind, precision, sampling and cosine fraction of a BSDF's properties."""
    import mitsuba as mi

    if "filename" not in props:
        raise ValueError("a bvae/merl BSDF needs a 'filename' property (.bvae or MERL .binary file)")
    filename = str(props["filename"])
    resolver = mi.file_resolver() if hasattr(mi, "file_resolver") else mi.Thread.thread().file_resolver()
    resolved = str(resolver.resolve(filename))
    precision = str(props["precision"]) if "precision" in props else "float32"
    if precision not in ("float32", "float16"):
        raise ValueError(f"{filename}: 'precision' must be float32 or float16, got {precision!r}")
    sampling = str(props["sampling"]) if "sampling" in props else "tabulated"
    if sampling not in ("tabulated", "theta_h", "cosine"):
        raise ValueError(f"{filename}: 'sampling' must be tabulated, theta_h or cosine, got {sampling!r}")
    fraction = float(props["cosine_fraction"]) if "cosine_fraction" in props else None
    if fraction is not None and not 0.0 < fraction <= 1.0:
        raise ValueError(f"{filename}: 'cosine_fraction' must be in (0, 1], got {fraction}")
    lookup = str(props["lookup"]) if "lookup" in props else "nearest"
    if lookup not in ("nearest", "trilinear"):
        raise ValueError(f"{filename}: 'lookup' must be nearest or trilinear, got {lookup!r}")
    return {
        "filename": resolved,
        "material": str(props["material"]) if "material" in props else None,
        "kind": default_kind,
        "precision": precision,
        "sampling": sampling,
        "cosine_fraction": 1.0 if sampling == "cosine" else fraction,
        "lookup": lookup,
    }


def _describe(name: str, tables: MaterialTables, sampling: str) -> str:
    return (f"BvaeBSDF[material={name!r}, source={tables.source!r}, precision={tables.precision}, "
            f"table={tables.nbytes / 1e6:.1f} MB, sampling={sampling}]")


def _tables_of(props: Any, default_kind: str) -> tuple[dict[str, Any], Any]:
    """A plug-in's validated properties and the material tables they name (shared by both plug-in classes)."""
    options = _source_properties(props, default_kind)
    tables = material_tables(options["filename"], options["material"], precision=options["precision"],
                             kind=options["kind"])
    return options, tables


def _scalar_class(mi: Any, default_kind: str) -> type:
    class ScalarBvaeBSDF(mi.BSDF):  # type: ignore[misc, name-defined]
        """A brdfcodec material as a Mitsuba BSDF for scalar variants (reflection only, one-sided)."""

        def __init__(self, props: Any) -> None:
            mi.BSDF.__init__(self, props)
            options, self.tables = _tables_of(props, default_kind)
            self.name = self.tables.name
            channels_last = self.tables.host().reshape(N_THETA_H, N_THETA_D, N_PHI_D, 3)
            self.table = np.moveaxis(channels_last, -1, 0)  # a view: (3, 90, 90, 180)
            self.scale = self.tables.scale
            self.lookup = options["lookup"]
            if self.lookup == "trilinear":  # brdfcodec.representation.lookup's inputs, made once
                self.table = np.ascontiguousarray(self.table, dtype=np.float32)
                self.mask = self.table >= 0
            self.m_flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        def _value(self, wi: Any, wo: Any) -> Any:
            if wi.z <= 0 or wo.z <= 0:
                return mi.Color3f(0.0)
            a, b = (float(wi.x), float(wi.y), float(wi.z)), (float(wo.x), float(wo.y), float(wo.z))
            if self.lookup == "nearest":
                rgb = nearest_value(self.table, a, b) * self.scale
            else:
                from brdfcodec.representation.lookup import lookup

                rgb = lookup(self.table, a, b, mode="trilinear", mask=self.mask) * self.scale
            return mi.Color3f(float(rgb[0]), float(rgb[1]), float(rgb[2]))

        def eval(self, ctx: Any, si: Any, wo: Any, active: bool = True) -> Any:
            return self._value(si.wi, wo) * max(float(wo.z), 0.0)

        def pdf(self, ctx: Any, si: Any, wo: Any, active: bool = True) -> Any:
            if si.wi.z <= 0 or wo.z <= 0:
                return 0.0
            return float(wo.z) / math.pi

        def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: bool = True) -> Any:
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: bool = True) -> Any:
            bs = mi.BSDFSample3f()
            if si.wi.z <= 0:
                return bs, mi.Color3f(0.0)
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.wo = wo
            bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(wo)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = 0
            if bs.pdf <= 0:
                return bs, mi.Color3f(0.0)
            return bs, self._value(si.wi, wo) * math.pi  # f · cos / pdf with pdf = cos / π

        def traverse(self, callback: Any) -> None:
            callback.put("scale", self.scale, +mi.ParamFlags.NonDifferentiable)

        def to_string(self) -> str:
            return _describe(self.name, self.tables, "cosine")

    return ScalarBvaeBSDF


def _vector_class(mi: Any, default_kind: str) -> type:
    import sys

    import drjit as dr

    array_module = sys.modules[mi.Float16.__module__]
    half_pi = math.pi / 2
    edges_sin2 = np.sin(theta_h_edges()) ** 2
    band = np.diff(edges_sin2)

    def coordinates(wi: Any, wo: Any) -> tuple[Any, Any, Any, Any]:
        """(θh, θd, φd folded into [0, π], half vector) of unit direction pairs, spec/conventions.md §3."""
        h = dr.normalize(wi + wo)
        rxy = dr.sqrt(dr.fma(h.x, h.x, h.y * h.y))
        theta_h = dr.atan2(rxy, h.z)
        axis = rxy > 1e-12
        c = dr.select(axis, h.x / rxy, 1.0)  # cos φh
        s = dr.select(axis, h.y / rxy, 0.0)  # sin φh
        x1 = c * wi.x + s * wi.y  # ωi rotated by −φh about z
        y1 = c * wi.y - s * wi.x
        x2 = x1 * h.z - wi.z * rxy  # then by −θh about y
        z2 = x1 * rxy + wi.z * h.z
        theta_d = dr.atan2(dr.sqrt(dr.fma(x2, x2, y1 * y1)), z2)
        phi_d = dr.atan2(y1, x2)
        phi_d = dr.select(phi_d < 0, phi_d + math.pi, phi_d)  # fold by reciprocity into [0, π]
        return theta_h, theta_d, phi_d, h

    def bins(wi: Any, wo: Any) -> tuple[Any, Any, Any, Any]:
        """(θh bin, θd bin, φd bin, half vector) of unit direction pairs, spec/conventions.md §3."""
        theta_h, theta_d, phi_d, h = coordinates(wi, wo)
        i_h = mi.Int32(dr.floor(N_THETA_H * dr.sqrt(dr.maximum(theta_h, 0.0) / half_pi) + BIN_TOLERANCE))
        i_d = mi.Int32(dr.floor(N_THETA_D * theta_d / half_pi + BIN_TOLERANCE))
        i_p = mi.Int32(dr.floor(N_PHI_D * phi_d / math.pi + BIN_TOLERANCE))
        i_h = dr.clip(i_h, 0, N_THETA_H - 1)
        i_d = dr.clip(i_d, 0, N_THETA_D - 1)
        i_p = dr.select(i_p >= N_PHI_D, i_p - N_PHI_D, dr.maximum(i_p, 0))  # φd = π is bin 0
        return mi.UInt32(i_h), mi.UInt32(i_d), mi.UInt32(i_p), h

    def corners(u: Any, n: int, periodic: bool) -> tuple[Any, Any, Any]:
        """Lower and upper neighbouring bins of bin coordinate u and the upper one's weight (as lookup)."""
        if periodic:
            lower = dr.floor(u)
            frac = u - lower
            low = mi.Int32(lower)
            low = dr.select(low >= n, low - n, low)
            high = dr.select(low + 1 >= n, low + 1 - n, low + 1)
            return mi.UInt32(low), mi.UInt32(high), frac
        clamped = dr.clip(u, 0.0, n - 1.0)
        low = dr.minimum(mi.Int32(dr.floor(clamped)), n - 2)
        return mi.UInt32(low), mi.UInt32(low + 1), clamped - mi.Float(low)

    class VectorBvaeBSDF(mi.BSDF):  # type: ignore[misc, name-defined]
        """A brdfcodec material as a vectorised Mitsuba BSDF (reflection only, one-sided)."""

        def __init__(self, props: Any) -> None:
            mi.BSDF.__init__(self, props)
            options, self.tables = _tables_of(props, default_kind)
            self.name = self.tables.name
            self.sampling = options["sampling"]
            self.lookup = options["lookup"]
            variant = mi.variant()
            if self.sampling == "tabulated":
                self.tables.warps()  # built from the host table while it is there (no copy back from the device)
            device = self.tables.device.get(variant)
            if device is None:  # upload once per variant, shared by every BSDF using these tables
                array_type = mi.Float16 if self.tables.precision == "float16" else mi.Float
                device = self.tables.device[variant] = array_type(self.tables.host())
                self.tables.release_host()
            self.m_values = device
            self.m_gather_type = array_module.Array3f16 if self.tables.precision == "float16" else mi.Color3f
            self.m_scale = float(self.tables.scale)
            self.m_warps = self._device_warps(variant) if self.sampling == "tabulated" else None
            fraction = options["cosine_fraction"]
            marginal = self.tables.marginal
            if self.m_warps is not None:
                self.m_cosine_fraction = WARP_COSINE_SHARE if fraction is None else fraction
            else:
                self.m_cosine_fraction = cosine_share(marginal) if fraction is None else fraction
                if self.sampling == "tabulated" or not marginal.sum() > 0:
                    self.m_cosine_fraction = 1.0  # a black or non-finite material: nothing to sample by
            self.m_marginal = mi.Float(marginal)
            self.m_band = mi.Float(band)
            self.m_edges_sin2 = mi.Float(edges_sin2)
            self.m_distribution = mi.DiscreteDistribution(mi.Float(np.where(marginal.sum() > 0, marginal, 1.0)))
            self.m_flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        @property
        def nbytes(self) -> int:
            """Bytes of the material's table (shared with other BSDFs of the same material)."""
            return self.tables.nbytes

        def reflectance(self, wi: Any, wo: Any, active: Any = True) -> Any:
            """Reflectance (1/sr, RGB) at unit local-frame direction pairs, 0 at or below the horizon."""
            active = active & (wi.z > HORIZON_COS_MIN) & (wo.z > HORIZON_COS_MIN)
            if self.lookup == "trilinear":
                return self._trilinear(wi, wo, active)
            i_h, i_d, i_p, _ = bins(wi, wo)
            index = (i_h * N_THETA_D + i_d) * N_PHI_D + i_p
            rgb = mi.Color3f(dr.gather(self.m_gather_type, self.m_values, index, active))
            return dr.select(active, dr.maximum(rgb, 0.0) * self.m_scale, 0.0)

        def _trilinear(self, wi: Any, wo: Any, active: Any) -> Any:
            """Interpolation between the 8 neighbouring bins, invalid entries left out (as lookup)."""
            theta_h, theta_d, phi_d, _ = coordinates(wi, wo)
            axes = (corners(N_THETA_H * dr.sqrt(dr.maximum(theta_h, 0.0) / half_pi), N_THETA_H, False),
                    corners(N_THETA_D * theta_d / half_pi, N_THETA_D, False),
                    corners(N_PHI_D * phi_d / math.pi, N_PHI_D, True))
            total, weights = mi.Color3f(0.0), mi.Color3f(0.0)
            for corner in range(8):
                picks = [(high, frac) if (corner >> axis) & 1 else (low, 1.0 - frac)
                         for axis, (low, high, frac) in enumerate(axes)]
                index = (picks[0][0] * N_THETA_D + picks[1][0]) * N_PHI_D + picks[2][0]
                weight = picks[0][1] * picks[1][1] * picks[2][1]
                rgb = mi.Color3f(dr.gather(self.m_gather_type, self.m_values, index, active))
                valid_weight = dr.select(rgb >= 0, mi.Color3f(weight), 0.0)
                total += valid_weight * dr.maximum(rgb, 0.0)
                weights += valid_weight
            value = dr.select(weights > 0, total / dr.maximum(weights, 1e-30), 0.0) * self.m_scale
            return dr.select(active, value, 0.0)

        def _device_warps(self, variant: str) -> tuple[Any, Any] | None:
            """The material's luminance and VNDF warps as Mitsuba's Marginal2D (built once per variant)."""
            built = self.tables.device_warps
            if variant not in built:
                warps = self.tables.warps()
                if warps is None:
                    built[variant] = None
                else:
                    params = [[float(t) for t in warps.theta_i]]
                    built[variant] = (mi.MarginalContinuous2D1(warps.luminance, params, normalize=True),
                                      mi.MarginalContinuous2D1(warps.vndf, params, normalize=True))
            return built[variant]

        def _warp_pdf(self, wi: Any, wo: Any, active: Any) -> Any:
            """Density over ωo (1/sr) of the luminance then VNDF warps (as Mitsuba's ``measured`` samples)."""
            luminance, vndf = self.m_warps
            m = dr.normalize(wi + wo)
            cos_i = dr.dot(wi, m)
            active = active & (cos_i > 0)
            theta_i = dr.safe_acos(wi.z)
            phi_i = dr.atan2(wi.y, wi.x)
            sin_m = dr.sqrt(dr.fma(m.x, m.x, m.y * m.y))
            theta_m = dr.atan2(sin_m, m.z)
            u_phi = (dr.atan2(m.y, m.x) - phi_i) * (0.5 / math.pi) + 0.5
            u_m = mi.Point2f(dr.sqrt(theta_m / half_pi), u_phi - dr.floor(u_phi))
            params = [theta_i]
            point, vndf_pdf = vndf.invert(u_m, params, active)
            lum_pdf = luminance.eval(point, params, active)
            jacobian = dr.maximum(2.0 * math.pi * math.pi * u_m.x * sin_m, 1e-6) * 4.0 * cos_i
            return dr.select(active, vndf_pdf * lum_pdf / jacobian, 0.0)

        def _warp_sample(self, wi: Any, sample2: Any, active: Any) -> Any:
            """ωo drawn by the luminance then VNDF warps (the reflection of ωi about the warped normal)."""
            luminance, vndf = self.m_warps
            params = [dr.safe_acos(wi.z)]
            point, _ = luminance.sample(mi.Point2f(sample2.y, sample2.x), params, active)
            u_m, _ = vndf.sample(point, params, active)
            theta_m = dr.square(u_m.x) * half_pi
            phi_m = (2.0 * u_m.y - 1.0) * math.pi + dr.atan2(wi.y, wi.x)
            sin_t, cos_t = dr.sincos(theta_m)
            sin_p, cos_p = dr.sincos(phi_m)
            return mi.reflect(wi, mi.Vector3f(sin_t * cos_p, sin_t * sin_p, cos_t))

        def _pdf(self, wi: Any, wo: Any, active: Any) -> Any:
            active = active & (wi.z > 0) & (wo.z > 0)
            cosine = mi.warp.square_to_cosine_hemisphere_pdf(wo)
            fraction = self.m_cosine_fraction
            if fraction >= 1.0:
                return dr.select(active, cosine, 0.0)
            if self.m_warps is not None:
                return dr.select(active, fraction * cosine + (1.0 - fraction) * self._warp_pdf(wi, wo, active), 0.0)
            i_h, _, _, h = bins(wi, wo)
            p_bin = dr.gather(mi.Float, self.m_marginal, i_h, active)
            p_bin_band = dr.gather(mi.Float, self.m_band, i_h, active)
            p_half = p_bin * h.z / (math.pi * dr.maximum(p_bin_band, 1e-30))  # density over half vectors
            p_reflected = p_half / (4.0 * dr.maximum(dr.abs(dr.dot(wo, h)), 1e-12))
            return dr.select(active, fraction * cosine + (1.0 - fraction) * p_reflected, 0.0)

        def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            return self.reflectance(si.wi, wo, active) * dr.maximum(wo.z, 0.0)

        def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            return self._pdf(si.wi, wo, active)

        def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            return self.eval(ctx, si, wo, active), self._pdf(si.wi, wo, active)

        def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True) -> Any:
            wi = si.wi
            active = active & (wi.z > 0)
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            fraction = self.m_cosine_fraction
            if fraction < 1.0 and self.m_warps is not None:
                wo = dr.select(sample1 < fraction, wo, self._warp_sample(wi, sample2, active))
            elif fraction < 1.0:
                use_cosine = sample1 < fraction
                remapped = dr.clip((sample1 - fraction) / (1.0 - fraction), 0.0, 1.0)
                index = self.m_distribution.sample(remapped, active)
                low = dr.gather(mi.Float, self.m_edges_sin2, index, active)
                high = dr.gather(mi.Float, self.m_edges_sin2, index + 1, active)
                sin2 = dr.clip(dr.fma(sample2.x, high - low, low), 0.0, 1.0)
                sin_t, cos_t = dr.sqrt(sin2), dr.sqrt(1.0 - sin2)
                sin_p, cos_p = dr.sincos(2.0 * math.pi * sample2.y)
                half = mi.Vector3f(sin_t * cos_p, sin_t * sin_p, cos_t)
                wo = dr.select(use_cosine, wo, mi.reflect(wi, half))
            value = self.reflectance(wi, wo, active)
            pdf = self._pdf(wi, wo, active)
            active = active & (wo.z > 0) & (pdf > 0)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = wo
            bs.pdf = dr.select(active, pdf, 0.0)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            weight = value * wo.z / dr.select(active, pdf, 1.0)
            return bs, dr.select(active, weight, 0.0)

        def traverse(self, callback: Any) -> None:
            callback.put("reflectance", self.m_values, +mi.ParamFlags.NonDifferentiable)
            callback.put("scale", self.m_scale, +mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys: Any = None) -> None:
            pass

        def to_string(self) -> str:
            if self.m_cosine_fraction >= 1:
                return _describe(self.name, self.tables, "cosine")
            kind = "luminance and VNDF warps" if self.m_warps is not None else "θh marginal"
            return _describe(self.name, self.tables, f"{kind} + {self.m_cosine_fraction:g} cosine")

    return VectorBvaeBSDF


_CLASSES: dict[tuple[str, str], type] = {}


def bsdf_class(kind: str = "auto") -> type:
    """The BSDF class of the current Mitsuba variant (scalar or vectorised), for ``kind`` "auto" or "merl"."""
    mi = _mitsuba()
    key = (mi.variant(), kind)
    if key not in _CLASSES:
        build = _scalar_class if mi.variant().startswith("scalar") else _vector_class
        _CLASSES[key] = build(mi, kind)
    return _CLASSES[key]


def register() -> None:
    """Register the ``bvae`` and ``merl`` BSDFs with the current Mitsuba variant.

    When no variant is set, :func:`brdfcodec.runtime.mitsuba.set_variant` sets
    ``llvm_ad_rgb`` if a usable libLLVM is found, else ``scalar_rgb`` with a
    warning. Call again after switching variants.
    """
    mi = _mitsuba()
    auto, merl = bsdf_class("auto"), bsdf_class("merl")
    mi.register_bsdf(PLUGIN_NAME, lambda props: auto(props))
    mi.register_bsdf(MERL_PLUGIN_NAME, lambda props: merl(props))


def material_of(bsdf: Any) -> MaterialTables | None:
    """The :class:`MaterialTables` behind a loaded ``bvae``/``merl`` BSDF (else None)."""
    return getattr(bsdf, "tables", None)


def __getattr__(name: str) -> Any:
    """``BvaeBSDF``: the BSDF class of the current variant (the name earlier versions exported)."""
    if name == "BvaeBSDF":
        return bsdf_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
