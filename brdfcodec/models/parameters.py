"""What each latent dimension controls, measured by traversal (the model's named parameters).

For every dimension d, the decoder is run at ``base ± span`` along d (others
fixed) and a few appearance statistics of the decoded table are compared:

- diffuse and specular colour: change of ``ln(R) − ln(B)`` (red against
  blue) of the reflectance in a diffuse region (θh ≈ 50°) and at the
  specular peak (θh ≈ 0), both at θd ≈ 11°, φd = 90°;
- diffuse and specular level: change of ln(luminance) in those regions;
- lobe width: change of the half-maximum θh of the specular lobe, degrees;
- grazing: change of ln(grazing / near-normal luminance) at the peak.

The largest normalised change names the dimension. The *colour dimensions*
(used by green-channel grafting) are the ones whose decode changes the
red–blue balance most; they are found here, never hard-coded, and stored in
the model's manifest (``parameters``) by :func:`describe_parameters`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from brdfcodec.representation import reflectance_from_stored
from brdfcodec.representation.coords import theta_h_from_index

__all__ = ["DimensionEffect", "colour_dims_of", "describe_parameters", "measure_dimension_effects"]

_PHI_D_BIN = 90
_THETA_D = slice(5, 16)  # θd ≈ 5–16°
_DIFFUSE_THETA_H = slice(60, 76)  # θh ≈ 40–64°
_PEAK_THETA_H = slice(0, 3)
_GRAZING_THETA_D = slice(75, 86)
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
_TINY = 1e-3  # floor of the logs, 1/sr: keeps a vanishing lobe from dominating
_CHROMA_NAMES = {True: "blue→red", False: "red→blue"}


@dataclass(frozen=True)
class DimensionEffect:
    """Change of each statistic from ``base − span`` to ``base + span`` along one dimension.

    Attributes
    ----------
    dim : int
        Latent dimension (0-based).
    diffuse_colour, specular_colour : float
        Change of ln(R) − ln(B) (positive: towards red).
    diffuse_level, specular_level : float
        Change of ln(luminance).
    lobe_width_deg : float
        Change of the specular lobe's half-maximum θh, degrees.
    grazing : float
        Change of ln(grazing / near-normal luminance) at the peak.
    label : str
        What the dimension mostly controls.
    """

    dim: int
    diffuse_colour: float
    specular_colour: float
    diffuse_level: float
    specular_level: float
    lobe_width_deg: float
    grazing: float
    label: str

    @property
    def colour_strength(self) -> float:
        """|diffuse colour change| + |specular colour change|."""
        return abs(self.diffuse_colour) + abs(self.specular_colour)


def _statistics(reflectance: np.ndarray) -> dict[str, float]:
    """Statistics of one φd slice of reflectance (3, 90, 90)."""
    rgb_diffuse = reflectance[:, _DIFFUSE_THETA_H, _THETA_D].mean(axis=(1, 2))
    rgb_peak = reflectance[:, _PEAK_THETA_H, _THETA_D].mean(axis=(1, 2))
    profile = np.tensordot(_LUMINANCE, reflectance[:, :, _THETA_D].mean(axis=2), axes=1)  # over θh bins
    diffuse = float(_LUMINANCE @ rgb_diffuse)
    peak = float(_LUMINANCE @ rgb_peak)
    half = diffuse + 0.5 * (peak - diffuse)
    below = np.nonzero(profile < half)[0]
    width_bin = int(below[0]) if below.size else profile.size - 1
    grazing = float(np.tensordot(_LUMINANCE, reflectance[:, _PEAK_THETA_H, _GRAZING_THETA_D].mean(axis=(1, 2)), 1))
    return {
        "diffuse_colour": float(np.log(rgb_diffuse[0] + _TINY) - np.log(rgb_diffuse[2] + _TINY)),
        "specular_colour": float(np.log(rgb_peak[0] + _TINY) - np.log(rgb_peak[2] + _TINY)),
        "diffuse_level": float(np.log(diffuse + _TINY)),
        "specular_level": float(np.log(peak + _TINY)),
        "lobe_width_deg": float(np.degrees(theta_h_from_index(width_bin))),
        "grazing": float(np.log((grazing + _TINY) / (peak + _TINY))),
    }


def _label(change: dict[str, float]) -> str:
    scores = {
        "diffuse colour": abs(change["diffuse_colour"]),
        "specular colour": abs(change["specular_colour"]),
        "diffuse level": abs(change["diffuse_level"]),
        "specular level": abs(change["specular_level"]),
        "lobe width (haziness)": abs(change["lobe_width_deg"]) / 10.0,
        "grazing reflection": abs(change["grazing"]),
    }
    best = max(scores, key=scores.__getitem__)
    if best.endswith("colour"):
        key = "diffuse_colour" if best.startswith("diffuse") else "specular_colour"
        return f"{best} ({_CHROMA_NAMES[change[key] > 0]})"
    if best.startswith("lobe"):
        return f"{best}, {'wider' if change['lobe_width_deg'] > 0 else 'narrower'} with +z"
    key = {"diffuse level": "diffuse_level", "specular level": "specular_level", "grazing reflection": "grazing"}[best]
    return f"{best}, {'higher' if change[key] > 0 else 'lower'} with +z"


def measure_dimension_effects(
    decoder: Any, *, base: np.ndarray | None = None, span: float = 2.0
) -> list[DimensionEffect]:
    """Traversal statistics of every dimension of a decoder.

    Parameters
    ----------
    decoder : brdfcodec.codec.BrdfDecoder
    base : ndarray, shape (latent_dim,), optional
        Code to traverse around (the prior mean, zeros, by default).
    span : float, default 2.0
        Half-range of the traversal, in latent units (prior σ).
    """
    from brdfcodec.format.bvae import LatentRecord

    dim = decoder.latent_dim
    centre = np.zeros(dim, dtype=np.float32) if base is None else np.asarray(base, dtype=np.float32)
    effects = []
    for d in range(dim):
        stats = []
        for sign in (-1.0, 1.0):
            code = centre.copy()
            code[d] += sign * span
            table = decoder.table(LatentRecord("probe", code, np.ones(dim)), phi_d_bins=[_PHI_D_BIN], masked="zero")
            stats.append(_statistics(reflectance_from_stored(table[..., 0])))
        change = {k: stats[1][k] - stats[0][k] for k in stats[0]}
        effects.append(DimensionEffect(dim=d, label=_label(change), **change))
    return effects


def colour_dims_of(effects: list[DimensionEffect], count: int = 2) -> tuple[int, ...]:
    """The ``count`` dimensions that change the red–blue balance most, in increasing order."""
    ranked = sorted(effects, key=lambda e: e.colour_strength, reverse=True)
    return tuple(sorted(e.dim for e in ranked[:count]))


def describe_parameters(decoder: Any, *, span: float = 2.0) -> dict[str, Any]:
    """The ``parameters`` entry of a model manifest: colour dimensions and each dimension's effects."""
    effects = measure_dimension_effects(decoder, span=span)
    return {
        "method": f"traversal of ±{span:g} prior σ around z = 0; spec/model.md §named parameters",
        "colour_dims": list(colour_dims_of(effects)),
        "dimensions": [asdict(e) for e in effects],
    }


def parameters_markdown(parameters: dict[str, Any]) -> str:
    """A Markdown table of the named parameters (for the model card)."""
    lines = [
        "| z | controls | diffuse colour | specular colour | diffuse level | specular level "
        "| lobe width (°) | grazing |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in parameters["dimensions"]:
        lines.append(
            f"| {row['dim'] + 1} | {row['label']} | {row['diffuse_colour']:+.2f} | {row['specular_colour']:+.2f} | "
            f"{row['diffuse_level']:+.2f} | {row['specular_level']:+.2f} | {row['lobe_width_deg']:+.1f} | "
            f"{row['grazing']:+.2f} |"
        )
    dims = ", ".join(str(d + 1) for d in parameters["colour_dims"])
    lines.append("")
    lines.append(f"Colour dimensions used for green-channel grafting: z{dims} (1-based).")
    return "\n".join(lines)
