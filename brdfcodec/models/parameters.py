"""What each latent dimension controls, measured by traversal (the model's named parameters).

For every dimension d, the decoder is run at ``base ± span`` along d (others
fixed) and a few appearance statistics of the decoded table are compared:

- diffuse and specular colour: change of ``ln(R) − ln(B)`` (red against
  blue) of the reflectance in a diffuse region (θh ≈ 50°) and at the
  specular peak (θh ≈ 0), both at θd ≈ 11°, φd = 90°;
- diffuse and specular level: change of ln(luminance) in those regions;
- lobe width: change of the half-maximum θh of the specular lobe, degrees;
- grazing: change of ln(grazing / near-normal luminance) at the peak.

The largest normalised change names the dimension (:func:`distinct_labels`:
where several dimensions share their largest effect, each is told apart by its
next largest, and only dimensions alike in both get a letter). The *colour dimensions*
(used by green-channel grafting) are the ones whose decode changes the
red–blue balance most; they are found here, never hard-coded, and stored in
the model's manifest (``parameters``) by :func:`describe_parameters`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from brdfcodec.representation import reflectance_from_stored
from brdfcodec.representation.coords import theta_h_from_index

__all__ = ["DimensionEffect", "colour_dims_of", "describe_parameters", "distinct_labels", "measure_dimension_effects"]

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


#: The statistics that name a dimension, with the scale that makes their changes comparable (lobe width in
#: degrees is divided by 10), the words for an increase and a decrease, and their field in DimensionEffect.
_NAMED_STATISTICS = (
    ("diffuse colour", "diffuse_colour", 1.0, "redder diffuse colour", "bluer diffuse colour"),
    ("specular colour", "specular_colour", 1.0, "redder specular colour", "bluer specular colour"),
    ("diffuse level", "diffuse_level", 1.0, "brighter diffuse", "darker diffuse"),
    ("specular level", "specular_level", 1.0, "brighter highlight", "darker highlight"),
    ("lobe width (haziness)", "lobe_width_deg", 0.1, "wider lobe", "narrower lobe"),
    ("grazing reflection", "grazing", 1.0, "more grazing reflection", "less grazing reflection"),
)


def _ranked(change: dict[str, float]) -> list[tuple[str, str, float]]:
    """(statistic, field, normalised |change|), largest first."""
    scores = [(name, key, abs(float(change[key])) * scale) for name, key, scale, _, _ in _NAMED_STATISTICS]
    return sorted(scores, key=lambda item: -item[2])


def _phrase(name: str, key: str, change: dict[str, float]) -> str:
    """The long form: ``diffuse colour (red→blue)``, ``specular level, lower with +z``."""
    value = float(change[key])
    if name.endswith("colour"):
        return f"{name} ({_CHROMA_NAMES[value > 0]})"
    if key == "lobe_width_deg":
        return f"{name}, {'wider' if value > 0 else 'narrower'} with +z"
    return f"{name}, {'higher' if value > 0 else 'lower'} with +z"


def _short(key: str, change: dict[str, float]) -> str:
    _, _, _, up, down = next(s for s in _NAMED_STATISTICS if s[1] == key)
    return up if float(change[key]) > 0 else down


def _label(change: dict[str, float]) -> str:
    name, key, _ = _ranked(change)[0]
    return _phrase(name, key, change)


def distinct_labels(dimensions: list[dict[str, Any]]) -> list[str]:
    """One name per dimension, no two alike, from the measured statistics (a manifest's ``dimensions``).

    A dimension is named by its largest normalised effect (as ``label``). Where several dimensions share that
    statistic, each name adds the dimension's next largest effect (``"diffuse level, lower with +z; also
    darker highlight"``). A dimension aligned with a factor of appearance (an entry's ``factor``,
    ``bvae model export --align-factors``) is named by it first (``"roughness: specular level, lower with
    +z"``). Dimensions still alike get a letter, ``(a)``, ``(b)``, in dimension order.

    Parameters
    ----------
    dimensions : list of dict
        Entries with ``dim`` and the statistics of :class:`DimensionEffect`.

    Returns
    -------
    list of str
        Indexed by dimension (0-based).
    """
    rows = sorted(dimensions, key=lambda row: int(row["dim"]))
    primary = [_ranked(row)[0] for row in rows]
    labels = []
    for row, (name, key, _) in zip(rows, primary, strict=True):
        label = _phrase(name, key, row)
        if sum(1 for other in primary if other[0] == name) > 1:
            _, second, _ = _ranked(row)[1]
            label = f"{label}; also {_short(second, row)}"
        labels.append(f"{row['factor']}: {label}" if row.get("factor") else label)
    for label in set(labels):
        same = [i for i, other in enumerate(labels) if other == label]
        if len(same) > 1:
            for letter, i in zip("abcdefghijklmnopqrstuvwxyz", same, strict=False):
                labels[i] = f"{label} ({letter})"
    return labels


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
            table = decoder.decode(LatentRecord("probe", code, np.ones(dim)), phi_d_bins=[_PHI_D_BIN], masked="zero")
            stats.append(_statistics(reflectance_from_stored(table[..., 0])))
        change = {k: stats[1][k] - stats[0][k] for k in stats[0]}
        effects.append(DimensionEffect(dim=d, label=_label(change), **change))
    return effects


def colour_dims_of(effects: list[DimensionEffect], count: int = 2) -> tuple[int, ...]:
    """The ``count`` dimensions that change the red–blue balance most, in increasing order."""
    ranked = sorted(effects, key=lambda e: e.colour_strength, reverse=True)
    return tuple(sorted(e.dim for e in ranked[:count]))


def describe_parameters(decoder: Any, *, span: float = 2.0,
                        factors: Sequence[tuple[str, float]] = ()) -> dict[str, Any]:
    """The ``parameters`` entry of a model manifest: colour dimensions and each dimension's effects.

    Parameters
    ----------
    decoder : brdfcodec.codec.BrdfDecoder
    span : float, default 2.0
        Half-range of the traversals, prior σ.
    factors : sequence of (str, float), optional
        The factor each of the first dimensions is aligned with and the correlation of the two over the
        materials the alignment was fitted to (:class:`brdfcodec.training.alignment.FactorAlignment`); stored
        as ``factor`` and ``factor_correlation`` and named first in the label.
    """
    effects = measure_dimension_effects(decoder, span=span)
    dimensions = [asdict(e) for e in effects]
    for row, (factor, correlation) in zip(dimensions, factors, strict=False):
        row["factor"], row["factor_correlation"] = str(factor), float(correlation)
    for row, label in zip(dimensions, distinct_labels(dimensions), strict=True):
        row["label"] = label
    return {
        "method": f"traversal of ±{span:g} prior σ around z = 0; spec/model.md §named parameters",
        "colour_dims": list(colour_dims_of(effects)),
        "dimensions": dimensions,
    }


def parameters_markdown(parameters: dict[str, Any]) -> str:
    """A Markdown table of the named parameters (for the model card)."""
    lines = [
        "| z | controls | diffuse colour | specular colour | diffuse level | specular level "
        "| lobe width (°) | grazing |",
        "|---|---|---|---|---|---|---|---|",
    ]
    rows = sorted(parameters["dimensions"], key=lambda row: int(row["dim"]))
    for row, label in zip(rows, distinct_labels(rows), strict=True):
        lines.append(
            f"| {row['dim'] + 1} | {label} | {row['diffuse_colour']:+.2f} | {row['specular_colour']:+.2f} | "
            f"{row['diffuse_level']:+.2f} | {row['specular_level']:+.2f} | {row['lobe_width_deg']:+.1f} | "
            f"{row['grazing']:+.2f} |"
        )
    aligned = [row for row in rows if row.get("factor")]
    if aligned:
        lines += ["", "Aligned dimensions (`bvae model export --align-factors`) and the correlation of each with its "
                  "factor over the analytic materials the alignment was fitted to: "
                  + ", ".join(f"z{row['dim'] + 1} {row['factor']} {row['factor_correlation']:.2f}" for row in aligned)
                  + "."]
    dims = ", ".join(str(d + 1) for d in parameters["colour_dims"])
    lines.append("")
    lines.append(f"Colour dimensions used for green-channel grafting: z{dims} (1-based).")
    return "\n".join(lines)
