"""Whether a material's measured error lies within what its model's card reports for the material's family.

A model is measured per family (``bvae model evaluate --store``: the NBRDF
proxies of MERL and RGL, materials trained on and held out) and on its
training materials one by one (``info.summary``: the largest RelAE per
split). A material whose RelAE is far above the largest figure the card
gives for its family, or of a family the card never measured, decodes with
errors that the card's figures do not prepare a user for (a colour tint, a
dark pit in the highlight): :func:`card_range_warning` says so, and
``bvae compress`` prints it as a warning.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["FAR_FACTOR", "card_range_warning", "family_of"]

#: A RelAE "far outside" the card's range: above this multiple of the largest figure the card gives for the family.
FAR_FACTOR = 2.0

#: ``source_kind`` (record metadata) → (family in the card's rows, what the card measured of it).
_FAMILIES = {None: "merl", "nbrdf-proxy": "merl", "rgl-measured": "rgl"}


def family_of(meta: Mapping[str, Any]) -> str | None:
    """The card family of a record's source (``"merl"`` or ``"rgl"``), None for other sources (analytic)."""
    return _FAMILIES.get(meta.get("source_kind"))


def _card_maxima(info: Mapping[str, Any], family: str) -> dict[str, float]:
    """The largest mapped and linear RelAE the card reports for a family (means per split, and per-material
    maxima of the training data's family), or {} when it reports none."""
    found: dict[str, list[float]] = {"mapped": [], "linear": []}
    rows = (info.get("by_family") or {}).get("rows") or []
    for row in rows:
        if row.get("family") == family:
            for metric in found:
                if isinstance(row.get(metric), int | float):
                    found[metric].append(float(row[metric]))
    trained = {row.get("family") for row in rows if row.get("split") == "train"} or {"merl"}
    if family in trained:
        for split in (info.get("summary") or {}).values():
            for metric in found:
                if isinstance(split, Mapping) and isinstance(split.get(f"{metric}_max"), int | float):
                    found[metric].append(float(split[f"{metric}_max"]))
    return {metric: max(values) for metric, values in found.items() if values}


def card_range_warning(name: str, meta: Mapping[str, Any], info: Mapping[str, Any], model: str) -> str | None:
    """A warning when a record's measured RelAE is far outside its model card's range for its family, else None.

    Parameters
    ----------
    name : str
        Material name (for the message).
    meta : mapping
        The record's metadata: ``relae`` (mapped and linear RelAE, unitless) and ``source_kind``.
    info : mapping
        The model's ``model.json`` ``info`` (its card's measurements).
    model : str
        The model's name (for the message).

    Returns
    -------
    str or None
        None when the record has no RelAE, comes from a source with no card family (analytic), or lies within
        :data:`FAR_FACTOR` times the largest figure the card gives for its family.
    """
    relae = meta.get("relae")
    family = family_of(meta)
    if not isinstance(relae, Mapping) or family is None:
        return None
    maxima = _card_maxima(info, family)
    if meta.get("source_kind") == "rgl-measured":
        measured = f" (mapped {relae['mapped']:.4f})" if isinstance(relae.get("mapped"), int | float) else ""
        proxy = f"; on the NBRDF proxy of RGL it reports mapped {maxima['mapped']:.3f}" if "mapped" in maxima else ""
        return (f"{name}: measured RGL data{measured}: model {model}'s card has no measurement of such data"
                f"{proxy}; expect visible errors (colour tint, highlight shape) and check a render "
                "(bvae render --compare SOURCE)")
    far = [f"{metric} {relae[metric]:.4f} against at most {maxima[metric]:.4f}" for metric in ("mapped", "linear")
           if metric in maxima and isinstance(relae.get(metric), int | float)
           and relae[metric] > FAR_FACTOR * maxima[metric]]
    if not far:
        return None
    return (f"{name}: RelAE far outside model {model}'s card for {family} materials ({'; '.join(far)}): expect "
            "visible errors; check a render (bvae render --compare SOURCE)")
