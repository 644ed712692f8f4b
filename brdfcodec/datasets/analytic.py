"""Analytic BRDFs (Lambert + GGX microfacet lobe) tabulated on the MERL grid.

They let tests and demos run without measured data, and they give exact
control over extreme cases (mirror-like chrome, near-black, huge grazing
values). The model, in physical units (1/sr), per colour channel::

    f(wi, wo) = kd / π + ks_F · D(h) · G(wi, wo) / (4 cos θi cos θo)

with the GGX (Trowbridge–Reitz) distribution D of roughness α, the
separable Smith masking-shadowing G of GGX, and Schlick's Fresnel
``F = F0 + g · (1 − F0)(1 − wi·h)^5`` with F0 = ``specular`` and g =
``grazing`` (1: Schlick's). An optional sheen lobe ``s · (1 − wi·h)^5 / π``
(s = ``sheen``, white) adds broad grazing reflection, as Disney's sheen does.

:func:`sample_factor_materials` draws materials whose generating factors
(albedo level and hue, specular level, roughness, grazing Fresnel, sheen,
metalness) are sampled independently: the known factors of the
disentanglement benchmark (:mod:`brdfcodec.report.disentanglement`).
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Iterator
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import KEPT_PHI_D_SLICES, UNMEASURED_VALUE
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.representation import stored_from_reflectance
from brdfcodec.representation.coords import directions_from_half_diff, grid_angles
from brdfcodec.representation.mask import horizon_mask, kept_slice_horizon_mask

__all__ = [
    "ANALYTIC_PRESETS",
    "FACTOR_ALPHA_RANGE",
    "FACTOR_NAMES",
    "FACTOR_SATURATION",
    "SATURATION_FACTOR",
    "AnalyticBRDF",
    "FactorMaterials",
    "factor_material",
    "random_analytic_materials",
    "sample_factor_materials",
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
    grazing : float, default 1
        Weight g of Schlick's grazing term, in [0, 1]: 1 is Schlick's Fresnel,
        0 a constant F = F0 (no brightening towards grazing angles).
    sheen : float, default 0
        Weight s of a white sheen lobe ``s · (1 − wi·h)^5 / π`` (1/sr), in [0, 1].
    """

    name: str
    diffuse: tuple[float, float, float] | float = 0.5
    specular: tuple[float, float, float] | float = 0.04
    roughness: float = 0.2
    grazing: float = 1.0
    sheen: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "diffuse", _rgb(self.diffuse, "diffuse"))
        object.__setattr__(self, "specular", _rgb(self.specular, "specular"))
        if not 1e-4 <= float(self.roughness) <= 1.0:
            raise ValueError(f"roughness must be in [1e-4, 1], got {self.roughness!r}")
        for label in ("grazing", "sheen"):
            if not 0.0 <= float(getattr(self, label)) <= 1.0:
                raise ValueError(f"{label} must be in [0, 1], got {getattr(self, label)!r}")

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
        return self._from_cosines(*_cosines(wi, wo))

    def _from_cosines(
        self, above: np.ndarray, ci: np.ndarray, co: np.ndarray, cos_h: np.ndarray, cos_d: np.ndarray
    ) -> npt.NDArray[np.float64]:
        """Reflectance (..., 3) from the geometry terms of :func:`_cosines`."""
        a2 = float(self.roughness) ** 2
        distribution = a2 / (np.pi * ((a2 - 1.0) * cos_h**2 + 1.0) ** 2)

        def smith_g1(cos: np.ndarray) -> np.ndarray:
            return 2.0 * cos / (cos + np.sqrt(a2 + (1.0 - a2) * cos**2))

        geometry = smith_g1(ci) * smith_g1(co)
        f0 = np.asarray(self.specular)
        grazing = ((1.0 - cos_d) ** 5)[..., None]
        schlick = f0 + float(self.grazing) * (1.0 - f0) * grazing
        fresnel = np.where(f0 > 0, schlick, 0.0)  # specular = 0 switches the lobe off
        lobe = (distribution * geometry / (4.0 * ci * co))[..., None] * fresnel
        value = np.asarray(self.diffuse) / np.pi + lobe
        if self.sheen:
            value = value + float(self.sheen) / np.pi * grazing
        return np.where(above[..., None], value, 0.0)

    def kept_network_input(self) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
        """The network input and its mask, shape (63, 90, 90), computed on the 21 kept φd slices only.

        Equal (up to float rounding) to
        :func:`~brdfcodec.representation.network_input_from_table` of
        :meth:`to_merl`, and much faster, since it evaluates only the kept slices; the grid's geometry is
        computed once per process.
        """
        from brdfcodec.representation import to_network_layout
        from brdfcodec.representation.mapping import map_values

        value = np.moveaxis(self._from_cosines(*_kept_cosines()), -1, 0)  # (3, 90, 90, 21), 1/sr
        mask = np.broadcast_to(kept_slice_horizon_mask()[None], value.shape)
        stored = stored_from_reflectance(value)
        mapped = np.where(mask, map_values(np.where(mask, stored, 0.0)), 0.0).astype(np.float32)
        return to_network_layout(mapped), to_network_layout(np.array(mask))

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


def _cosines(wi: npt.ArrayLike, wo: npt.ArrayLike) -> tuple[np.ndarray, ...]:
    """Geometry terms of direction pairs: above the horizon, cos θi, cos θo (1 below), cos θh, cos θd."""
    wi_arr, wo_arr = np.broadcast_arrays(np.asarray(wi, float), np.asarray(wo, float))
    cos_i, cos_o = wi_arr[..., 2], wo_arr[..., 2]
    above = (cos_i > 0) & (cos_o > 0)
    ci = np.where(above, cos_i, 1.0)
    co = np.where(above, cos_o, 1.0)
    half = wi_arr + wo_arr
    half /= np.maximum(np.linalg.norm(half, axis=-1, keepdims=True), 1e-300)
    cos_h = np.clip(half[..., 2], 0.0, 1.0)
    cos_d = np.clip(np.sum(wi_arr * half, axis=-1), 0.0, 1.0)
    return above, ci, co, cos_h, cos_d


@functools.cache
def _kept_cosines() -> tuple[np.ndarray, ...]:
    """:func:`_cosines` of the MERL grid's 21 kept φd slices, shape (90, 90, 21) each (computed once)."""
    wi, wo = directions_from_half_diff(*grid_angles(list(KEPT_PHI_D_SLICES)))
    terms = _cosines(wi, wo)
    for term in terms:
        term.setflags(write=False)
    return terms


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


#: The generating factors of :func:`sample_factor_materials`, in column order; each is drawn uniformly in
#: [0, 1] and independently of the others (:func:`factor_material` says what each value means).
FACTOR_NAMES: tuple[str, ...] = ("albedo", "hue", "specular", "roughness", "grazing", "sheen", "metallic")

#: The optional eighth factor of :func:`sample_factor_materials`: the base colour's HSV saturation.
SATURATION_FACTOR = "saturation"

#: The HSV saturation of every colour of :func:`sample_factor_materials` without the saturation factor (the
#: disentanglement benchmark's).
FACTOR_SATURATION = 0.7


def _hue_rgb(hue: float, saturation: float = FACTOR_SATURATION) -> np.ndarray:
    """An RGB colour of the given hue (0 red, 1/3 green, 2/3 blue) and HSV saturation (0 grey), mean 1."""
    import colorsys

    rgb = np.asarray(colorsys.hsv_to_rgb(hue, saturation, 1.0))
    return rgb / rgb.mean()


def _log_lerp(low: float, high: float, u: float) -> float:
    return float(np.exp(np.log(low) + u * (np.log(high) - np.log(low))))


#: The GGX α range of the ``roughness`` factor (log-uniform between them) of the benchmark's materials.
FACTOR_ALPHA_RANGE: tuple[float, float] = (0.03, 0.6)


def factor_material(factors: npt.ArrayLike, name: str = "factor-material", *,
                    alpha_min: float = FACTOR_ALPHA_RANGE[0]) -> AnalyticBRDF:
    """The material of one factor vector (values in [0, 1], :data:`FACTOR_NAMES` order).

    Parameters
    ----------
    factors : array_like, shape (7,) or (8,)
        ``albedo``: base colour level (mean of R, G, B), log-uniform 0.02 to 0.8;
        ``hue``: base colour hue from red (0) through green (0.5) to blue (1),
        HSV saturation 0.7 unless an eighth value gives it (channels clipped to 1);
        ``specular``: dielectric F0, log-uniform 0.02 to 0.16;
        ``roughness``: GGX α, log-uniform ``alpha_min`` (0.03 by default) to 0.6;
        ``grazing``: weight of Schlick's grazing term, 0 to 1;
        ``sheen``: white sheen weight, 0 to 0.5;
        ``metallic``: m, 0 to 1: diffuse = (1 − m)·colour and
        F0 = (1 − m)·F0_dielectric + m·colour, so a metal's specular takes the base colour;
        an eighth value, ``saturation`` (:data:`SATURATION_FACTOR`), if given: the base colour's HSV
        saturation, 0 (grey) to 1; without it 0.7.
    name : str
        Material name.
    alpha_min : float, default 0.03
        The sharpest GGX α, at ``roughness`` 0 (in (0, 0.6)); the benchmark's materials use the default.

    Returns
    -------
    AnalyticBRDF
    """
    if not 0 < alpha_min < FACTOR_ALPHA_RANGE[1]:
        raise ValueError(f"alpha_min must be in (0, {FACTOR_ALPHA_RANGE[1]}), got {alpha_min}")
    values = np.asarray(factors, dtype=float).reshape(-1)
    if (values.size not in (len(FACTOR_NAMES), len(FACTOR_NAMES) + 1) or not np.isfinite(values).all()
            or (values < 0).any() or (values > 1).any()):
        raise ValueError(f"factors must be {len(FACTOR_NAMES)} values in [0, 1] ({', '.join(FACTOR_NAMES)}), "
                         f"optionally followed by {SATURATION_FACTOR}, got {values.tolist()}")
    albedo, hue, specular, roughness, grazing, sheen, metallic = (float(v) for v in values[:len(FACTOR_NAMES)])
    saturation = float(values[len(FACTOR_NAMES)]) if values.size > len(FACTOR_NAMES) else FACTOR_SATURATION
    colour = np.minimum(_log_lerp(0.02, 0.8, albedo) * _hue_rgb(hue * 2.0 / 3.0, saturation), 1.0)
    f0 = (1.0 - metallic) * _log_lerp(0.02, 0.16, specular) + metallic * colour
    return AnalyticBRDF(name, tuple((1.0 - metallic) * colour), tuple(np.maximum(f0, 1e-3)),  # type: ignore[arg-type]
                        _log_lerp(alpha_min, FACTOR_ALPHA_RANGE[1], roughness), grazing=grazing, sheen=0.5 * sheen)


@dataclass(frozen=True)
class FactorMaterials:
    """Materials with known, independently drawn generating factors.

    Attributes
    ----------
    materials : tuple of AnalyticBRDF
        Named ``factors-NNN``.
    factors : ndarray of float64, shape (N, K)
        Each material's factor values in [0, 1], columns ``names``.
    names : tuple of str
        :data:`FACTOR_NAMES` (K = 7), followed by :data:`SATURATION_FACTOR` when the colour's saturation
        was drawn too (K = 8).
    """

    materials: tuple[AnalyticBRDF, ...]
    factors: npt.NDArray[np.float64]
    names: tuple[str, ...] = FACTOR_NAMES


def sample_factor_materials(count: int, *, seed: int = 0, saturation: bool = False,
                            alpha_min: float = FACTOR_ALPHA_RANGE[0]) -> FactorMaterials:
    """Reproducible materials whose factors are drawn independently and uniformly in [0, 1].

    Parameters
    ----------
    count : int
        Number of materials, ≥ 1.
    seed : int, default 0
        Seed; material i depends only on (seed, i), not on ``count``.
    saturation : bool, default False
        Draw the base colour's saturation as an eighth factor (:data:`SATURATION_FACTOR`, 0 grey to 1), so
        that grey and white materials are among them; without it every colour has saturation 0.7 (the
        disentanglement benchmark's materials). Material i's first seven factors are the same either way.
    alpha_min : float, default 0.03
        The sharpest GGX α of the ``roughness`` factor (:func:`factor_material`): lower it to draw sharper
        highlights; the factor values, and so the draws, are the same.

    Returns
    -------
    FactorMaterials
    """
    if count < 1:
        raise ValueError(f"count must be ≥ 1, got {count}")
    rows, materials = [], []
    for index in range(count):
        digest = hashlib.sha256(f"brdfcodec-factors:{seed}:{index}".encode()).digest()
        rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
        values = rng.random(len(FACTOR_NAMES))
        if saturation:
            values = np.append(values, rng.random())
        rows.append(values)
        materials.append(factor_material(values, f"factors-{index:03d}", alpha_min=alpha_min))
    names = (*FACTOR_NAMES, SATURATION_FACTOR) if saturation else FACTOR_NAMES
    return FactorMaterials(tuple(materials), np.asarray(rows), names)
