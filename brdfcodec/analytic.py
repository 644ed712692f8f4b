"""Analytic BRDFs (Lambert + GGX microfacet lobe) tabulated on the MERL grid.

They let tests and demos run without measured data, and they give exact
control over extreme cases (mirror-like chrome, near-black, huge grazing
values). The model, in physical units (1/sr), per colour channel::

    f(wi, wo) = kd / π + ks_F · D(h) · G(wi, wo) / (4 cos θi cos θo)

with the GGX (Trowbridge–Reitz) distribution D of roughness α, the
separable Smith masking-shadowing G of GGX, and Schlick's Fresnel
``F = F0 + (1 − F0)(1 − wi·h)^5`` with F0 = ``specular``.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import UNMEASURED_VALUE
from brdfcodec.coords import directions_from_half_diff, grid_angles
from brdfcodec.mask import horizon_mask
from brdfcodec.merl import MerlBRDF
from brdfcodec.representation import stored_from_reflectance

__all__ = [
    "ANALYTIC_PRESETS",
    "AnalyticBRDF",
    "random_analytic_materials",
]


def _rgb(value: tuple[float, float, float] | float, label: str) -> tuple[float, float, float]:
    triple = (float(value),) * 3 if np.isscalar(value) else tuple(float(v) for v in value)  # type: ignore[union-attr]
    if len(triple) != 3 or not all(np.isfinite(triple)) or min(triple) < 0:
        raise ValueError(f"{label} must be one or three finite non-negative numbers, got {value!r}")
    return triple  # type: ignore[return-value]


@dataclass(frozen=True)
class AnalyticBRDF:
    """Lambert + GGX material.

    Parameters
    ----------
    name : str
        Material name.
    diffuse : float or (float, float, float)
        Lambertian albedo per channel, in [0, 1].
    specular : float or (float, float, float)
        Fresnel reflectance at normal incidence (F0) per channel, in [0, 1];
        0 means no specular lobe in that channel (not even at grazing angles).
    roughness : float
        GGX α, in [1e-4, 1]. Small values give mirror-like peaks.
    """

    name: str
    diffuse: tuple[float, float, float] | float = 0.5
    specular: tuple[float, float, float] | float = 0.04
    roughness: float = 0.2

    def __post_init__(self) -> None:
        object.__setattr__(self, "diffuse", _rgb(self.diffuse, "diffuse"))
        object.__setattr__(self, "specular", _rgb(self.specular, "specular"))
        if not 1e-4 <= float(self.roughness) <= 1.0:
            raise ValueError(f"roughness must be in [1e-4, 1], got {self.roughness!r}")

    def evaluate(self, wi: npt.ArrayLike, wo: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Reflectance (1/sr) for direction pairs; 0 below the horizon.

        Parameters
        ----------
        wi, wo : array_like, shape (..., 3)
            Unit directions in the shading frame.

        Returns
        -------
        ndarray, shape (..., 3)
        """
        wi_arr, wo_arr = np.broadcast_arrays(np.asarray(wi, float), np.asarray(wo, float))
        cos_i, cos_o = wi_arr[..., 2], wo_arr[..., 2]
        above = (cos_i > 0) & (cos_o > 0)
        ci = np.where(above, cos_i, 1.0)
        co = np.where(above, cos_o, 1.0)
        half = wi_arr + wo_arr
        half /= np.maximum(np.linalg.norm(half, axis=-1, keepdims=True), 1e-300)
        cos_h = np.clip(half[..., 2], 0.0, 1.0)
        cos_d = np.clip(np.sum(wi_arr * half, axis=-1), 0.0, 1.0)
        a2 = float(self.roughness) ** 2
        distribution = a2 / (np.pi * ((a2 - 1.0) * cos_h**2 + 1.0) ** 2)

        def smith_g1(cos: np.ndarray) -> np.ndarray:
            return 2.0 * cos / (cos + np.sqrt(a2 + (1.0 - a2) * cos**2))

        geometry = smith_g1(ci) * smith_g1(co)
        f0 = np.asarray(self.specular)
        schlick = f0 + (1.0 - f0) * ((1.0 - cos_d) ** 5)[..., None]
        fresnel = np.where(f0 > 0, schlick, 0.0)  # specular = 0 switches the lobe off
        lobe = (distribution * geometry / (4.0 * ci * co))[..., None] * fresnel
        value = np.asarray(self.diffuse) / np.pi + lobe
        return np.where(above[..., None], value, 0.0)

    def reflectance(self) -> npt.NDArray[np.float64]:
        """Reflectance (1/sr) on the MERL grid, shape (3, 90, 90, 180); 0 below the horizon."""
        wi, wo = directions_from_half_diff(*grid_angles())
        return np.moveaxis(self.evaluate(wi, wo), -1, 0)

    #: Former name of :meth:`reflectance`.
    physical_table = reflectance

    def to_merl(self) -> MerlBRDF:
        """The material as a MERL table (stored units; below-horizon entries unmeasured)."""
        stored = stored_from_reflectance(self.reflectance())
        stored = np.where(horizon_mask()[None], stored, UNMEASURED_VALUE)
        return MerlBRDF(np.ascontiguousarray(stored), name=self.name)


#: Built-in materials, chosen to span ordinary and extreme cases.
ANALYTIC_PRESETS = MappingProxyType(
    {
        preset.name: preset
        for preset in (
            AnalyticBRDF("red-plastic", diffuse=(0.45, 0.05, 0.04), specular=0.04, roughness=0.12),
            AnalyticBRDF("green-satin", diffuse=(0.05, 0.35, 0.08), specular=0.04, roughness=0.3),
            AnalyticBRDF("blue-rubber", diffuse=(0.04, 0.08, 0.4), specular=0.03, roughness=0.5),
            AnalyticBRDF("white-matte", diffuse=0.8, specular=0.0, roughness=1.0),
            AnalyticBRDF("gold", diffuse=0.0, specular=(1.0, 0.77, 0.33), roughness=0.18),
            AnalyticBRDF("chrome", diffuse=0.0, specular=0.95, roughness=0.01),
            AnalyticBRDF("black-obsidian", diffuse=0.002, specular=0.04, roughness=0.03),
        )
    }
)


def random_analytic_materials(count: int, *, seed: int = 0) -> Iterator[AnalyticBRDF]:
    """Reproducible random Lambert + GGX materials named ``analytic-NNN``.

    Parameters
    ----------
    count : int
        Number of materials, ≥ 0.
    seed : int, default 0
        Seed; material i depends only on (seed, i), not on ``count``.

    Yields
    ------
    AnalyticBRDF
        Diffuse albedo in [0, 0.8]³, F0 in [0.02, 1]³, α log-uniform in [0.02, 0.8].
    """
    if count < 0:
        raise ValueError(f"count must be ≥ 0, got {count}")
    for index in range(count):
        digest = hashlib.sha256(f"brdfcodec-analytic:{seed}:{index}".encode()).digest()
        rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
        metallic = rng.random() < 0.3
        diffuse = (0.0, 0.0, 0.0) if metallic else tuple(rng.uniform(0.0, 0.8, 3))
        specular = tuple(rng.uniform(0.3, 1.0, 3)) if metallic else (float(rng.uniform(0.02, 0.08)),) * 3
        roughness = float(np.exp(rng.uniform(np.log(0.02), np.log(0.8))))
        yield AnalyticBRDF(f"analytic-{index:03d}", diffuse, specular, roughness)  # type: ignore[arg-type]
