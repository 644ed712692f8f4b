"""The libraries a studio opened: materials by id, latents, and the model's named parameters.

The client names materials only by the ids this module hands out; it never
names a file. All libraries must use one decoder (the one given, or the one
the first library names). Records without a latent code (basis-only records,
format 2.1) have nothing a slider could move: they are left out of the
editor and listed by name (``without_latent``), so the client can say why.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.format.bvae import GraftRecord, LatentRecord, Record
from brdfcodec.studio import StudioError

__all__ = ["Catalogue", "StudioMaterial"]

#: Largest |value| a client may send for a latent parameter (prior σ units); keeps every decode finite.
PARAMETER_LIMIT = 20.0


@dataclass(frozen=True)
class StudioMaterial:
    """One material offered to the client.

    Attributes
    ----------
    id : str
        What the client calls it: the record's name, prefixed with the
        library's label when several libraries are open (``"lib/name"``).
    library : str
        Label of its library (the file's stem, made unique).
    record : LatentRecord or GraftRecord
    """

    id: str
    library: str
    record: Record


def _labels(paths: Sequence[Path]) -> list[str]:
    labels: list[str] = []
    for path in paths:
        label, n = path.stem, 2
        while label in labels:
            label, n = f"{path.stem}-{n}", n + 1
        labels.append(label)
    return labels


class Catalogue:
    """Open ``.bvae`` libraries for the studio.

    Parameters
    ----------
    paths : sequence of path-like, optional
        Libraries to open; the shipped example library
        (:func:`brdfcodec.examples.example_library`) by default.
    model : str or path-like, optional
        Model folder, model name or decoder SHA-256; by default the decoder the first
        library names.

    Raises
    ------
    BvaeFormatError, DecoderNotFoundError, DecoderMismatchError
        A library that cannot be read, or that needs another decoder.
    ValueError
        No material with a latent code in the libraries.
    """

    def __init__(self, paths: Sequence[str | os.PathLike[str]] | None = None, *, model: Any = None) -> None:
        from brdfcodec.codec import BrdfDecoder, MaterialLibrary
        from brdfcodec.examples import example_library
        from brdfcodec.format.bvae import read_header

        self.paths = [Path(p) for p in (paths or [example_library()])]
        first = read_header(self.paths[0])
        self.decoder = BrdfDecoder(model) if model is not None else BrdfDecoder.for_header(first)
        self.materials: dict[str, StudioMaterial] = {}
        #: Ids of the records left out because they have no latent code to edit (basis-only records).
        self.without_latent: list[str] = []
        labels = _labels(self.paths)
        for path, label in zip(self.paths, labels, strict=True):
            with MaterialLibrary(path, decoder=self.decoder) as library:
                for name in library.names:
                    material_id = name if len(self.paths) == 1 else f"{label}/{name}"
                    record = library.record(name)
                    if not getattr(record, "has_latent", True):
                        self.without_latent.append(material_id)
                        continue
                    self.materials[material_id] = StudioMaterial(material_id, label, record)
        if not self.materials:
            why = (f" ({len(self.without_latent)} record{'s' if len(self.without_latent) != 1 else ''} without a "
                   "latent code, which cannot be edited: re-encode them with `bvae compress --latent always`)"
                   if self.without_latent else "")
            raise ValueError(f"{self.paths[0]}: no material to edit in the given libraries{why}")

    @property
    def latent_dim(self) -> int:
        """Length of the latent code."""
        return self.decoder.latent_dim

    @property
    def colour_dims(self) -> tuple[int, ...]:
        """The model's colour dimensions (the grafting parameters act there)."""
        return tuple(self.decoder.colour_dims)

    def ids(self) -> list[str]:
        """Material ids, in library order."""
        return list(self.materials)

    def record(self, material_id: object) -> Record:
        """The record of a material id; :class:`StudioError` (404) for anything else."""
        if not isinstance(material_id, str) or material_id not in self.materials:
            shown = material_id if isinstance(material_id, str) and len(material_id) < 80 else "(invalid)"
            raise StudioError(f"no material {shown!r} in the opened libraries", status=404)
        return self.materials[material_id].record

    def codes(self) -> np.ndarray:
        """Every material's code ``mu``, shape (N, latent_dim), float32."""
        return np.stack([m.record.mu for m in self.materials.values()]).astype(np.float32)

    def parameter_labels(self) -> list[str]:
        """One name per latent dimension, no two alike, from the model's measured parameters (``model.json``).

        Named from the stored statistics by :func:`brdfcodec.models.parameters.distinct_labels`; "unnamed" where a
        manifest has none.
        """
        from brdfcodec.models.parameters import distinct_labels

        effects = self.decoder.manifest.parameters.get("dimensions", []) if self.decoder.manifest else []
        by_dim = {int(e["dim"]): e for e in effects if "dim" in e}
        if sorted(by_dim) != list(range(self.latent_dim)):
            return [str(by_dim.get(d, {}).get("label") or "unnamed") for d in range(self.latent_dim)]
        return distinct_labels([by_dim[d] for d in range(self.latent_dim)])

    def slider_range(self) -> float:
        """Half-width of every latent slider: 3 prior σ, widened to hold every material's μ."""
        return float(max(3.0, np.ceil(np.abs(self.codes()).max() * 10) / 10))

    def describe(self) -> dict[str, Any]:
        """What the client needs: materials (id, μ, σ, graft values), parameter names, the model."""
        materials = []
        for m in self.materials.values():
            record = m.record
            entry: dict[str, Any] = {
                "id": m.id,
                "name": record.name,
                "library": m.library,
                "mu": [float(v) for v in record.mu],
                "sigma": [float(v) for v in record.sigma],
                "graft": [float(v) for v in record.graft_values] if isinstance(record, GraftRecord) else None,
            }
            relae = record.meta.get("relae")
            if isinstance(relae, dict) and isinstance(relae.get("mapped"), int | float):
                entry["relae_mapped"] = float(relae["mapped"])
            materials.append(entry)
        reference = self.decoder.reference
        return {
            "libraries": _labels(self.paths),
            "materials": materials,
            "latent_dim": self.latent_dim,
            "labels": self.parameter_labels(),
            "colour_dims": list(self.colour_dims),
            "slider_range": self.slider_range(),
            "model": {"name": reference.name, "decoder_sha256": reference.sha256},
            "without_latent": list(self.without_latent),
        }

    # ----------------------------------------------------------------- requests

    def parse_code(self, values: object, *, what: str = "z", length: int | None = None) -> np.ndarray:
        """A client's parameter list as float32, checked: the right length, finite, within ±PARAMETER_LIMIT."""
        n = self.latent_dim if length is None else length
        if not isinstance(values, list) or len(values) != n:
            raise StudioError(f"{what} must be a list of {n} numbers")
        if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
            raise StudioError(f"{what} must hold numbers only")
        array = np.asarray(values, dtype=np.float64)
        if not np.isfinite(array).all() or (np.abs(array) > PARAMETER_LIMIT).any():
            raise StudioError(f"{what} values must be finite and within ±{PARAMETER_LIMIT:g}")
        return array.astype(np.float32)

    def edited_record(self, body: dict[str, Any], *, name: str = "studio-edit") -> Record:
        """A record from a request body ``{"z": [...], "graft": [...] | null, "base": id?}``.

        σ is the base material's when a base is named (for saving), else 1. When the base is a layered record
        and nothing is grafted, the result keeps its layers with the new code (``spec/bvae-format.md`` §4.4,
        "Edits"): the edited base plus the base material's residual.
        """
        z = self.parse_code(body.get("z"))
        graft = body.get("graft")
        base = self.record(body["base"]) if body.get("base") is not None else None
        sigma = base.sigma if base is not None else np.ones_like(z)
        # A code other than the base material's own is an edit: its decode is energy-bounded (spec §6.3).
        edited = base is None or graft is not None or not np.array_equal(z, np.asarray(base.mu, dtype=z.dtype))
        meta = {"edit": {"op": "studio"}} if edited else {}
        if graft is None:
            from brdfcodec.format.layered_record import LayeredRecord

            if isinstance(base, LayeredRecord):
                from brdfcodec.edit.latent_edits import with_parameters

                layered = with_parameters(base, z, name=name, edit={"op": "studio"}, sigma=sigma)
                return layered if edited else replace(layered, meta={})
            return LatentRecord(name, z, sigma, meta)
        values = self.parse_code(graft, what="graft", length=len(self.colour_dims))
        return GraftRecord(name, z, sigma, self.colour_dims, values, meta)
