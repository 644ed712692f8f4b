"""Mitsuba 3 plug-in: a BSDF that reads a material from a ``.bvae`` file (optional extra ``brdfcodec[mitsuba]``).

Usage::

    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    import brdfcodec.mitsuba_bsdf
    brdfcodec.mitsuba_bsdf.register()
    bsdf = {"type": "bvae", "filename": "lib.bvae", "material": "gold"}

The material is decoded once when the scene loads (its decoder is found by the
file's SHA-256) and evaluated by table lookup (nearest bin, as MERL's reader,
or ``"lookup": "trilinear"``). Sampling is cosine-weighted over the upper
hemisphere, which is unbiased for any BRDF (noisy for very sharp lobes).
Only the ``scalar_rgb`` variant is supported: Mitsuba calls Python plug-ins
once per sample there, which is slow but exact; the ``llvm_*`` variants need
a working libLLVM, which is not assumed.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["PLUGIN_NAME", "BvaeBSDF", "nearest_value", "register"]

PLUGIN_NAME = "bvae"
_SUPPORTED_VARIANTS = ("scalar_rgb",)


def _mitsuba() -> Any:
    try:
        import mitsuba as mi
    except ImportError as error:  # pragma: no cover - optional extra
        raise ImportError("the Mitsuba plug-in needs Mitsuba 3: pip install 'brdfcodec[mitsuba]'") from error
    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    if mi.variant() not in _SUPPORTED_VARIANTS:
        raise RuntimeError(f"brdfcodec's Mitsuba BSDF supports the variants {_SUPPORTED_VARIANTS}, not {mi.variant()}")
    return mi


_TOLERANCE = 1e-9  # BIN_TOLERANCE of spec/conventions.md §3
_HORIZON = 1e-9  # HORIZON_COS_MIN


def nearest_value(table: np.ndarray, wi: tuple[float, float, float], wo: tuple[float, float, float]) -> np.ndarray:
    """Nearest-bin lookup of one direction pair with scalar arithmetic (spec/conventions.md §3).

    Same bins as :func:`brdfcodec.lookup.lookup` in ``"nearest"`` mode, about
    50 times faster for a single pair (Mitsuba's scalar variants call the BSDF
    once per sample). ``table`` is physical reflectance with invalid entries 0.
    """
    n_i = math.sqrt(wi[0] * wi[0] + wi[1] * wi[1] + wi[2] * wi[2])
    n_o = math.sqrt(wo[0] * wo[0] + wo[1] * wo[1] + wo[2] * wo[2])
    if n_i == 0.0 or n_o == 0.0 or wi[2] / n_i <= _HORIZON or wo[2] / n_o <= _HORIZON:
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
    i = min(max(int(math.floor(90 * math.sqrt(theta_h / (math.pi / 2)) + _TOLERANCE)), 0), 89)
    j = min(max(int(math.floor(90 * theta_d / (math.pi / 2) + _TOLERANCE)), 0), 89)
    k = min(max(int(math.floor(180 * phi_d / math.pi + _TOLERANCE)), 0), 179)
    return table[:, i, j, k]


def _bsdf_class() -> type:
    mi = _mitsuba()

    class BvaeBSDF(mi.BSDF):  # type: ignore[misc, name-defined]
        """A brdfcodec material as a Mitsuba BSDF (reflection only, two-sided off)."""

        def __init__(self, props: Any) -> None:
            mi.BSDF.__init__(self, props)
            from brdfcodec.codec import MaterialLibrary

            filename = str(props["filename"])
            material = str(props["material"]) if "material" in props else None
            self.lookup_mode = str(props["lookup"]) if "lookup" in props else "nearest"
            with MaterialLibrary(filename) as library:
                name = material or library.names[0]
                decoded = library[name]
                self.material = decoded
                self.table = np.ascontiguousarray(decoded.physical(), dtype=np.float64)
            self.name = name
            self.m_flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        def _value(self, wi: Any, wo: Any) -> Any:
            if wi.z <= 0 or wo.z <= 0:
                return mi.Color3f(0.0)
            a = (float(wi.x), float(wi.y), float(wi.z))
            b = (float(wo.x), float(wo.y), float(wo.z))
            if self.lookup_mode == "nearest":
                rgb = nearest_value(self.table, a, b)
            else:
                rgb = self.material.eval(np.array(a), np.array(b), mode="trilinear")
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

        def to_string(self) -> str:
            return f"BvaeBSDF[material={self.name!r}]"

    return BvaeBSDF


BvaeBSDF: type | None = None


def register() -> None:
    """Register the ``bvae`` BSDF with Mitsuba (sets the ``scalar_rgb`` variant if none is set)."""
    global BvaeBSDF
    mi = _mitsuba()
    BvaeBSDF = _bsdf_class()
    mi.register_bsdf(PLUGIN_NAME, lambda props: BvaeBSDF(props))  # type: ignore[misc]
