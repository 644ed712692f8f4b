"""Choosing the model, and preparing a source for the encoder: clamping, invalid bins, masks.

Part of :mod:`brdfcodec.codec`, which re-exports the public names.
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Literal

import numpy as np

from brdfcodec.conventions import MAPPED_MAX, UNMEASURED_VALUE
from brdfcodec.errors import (
    UnmeasuredMaterialError,
)
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.models.registry import resolve_manifest
from brdfcodec.models.store import ModelManifest
from brdfcodec.representation import (
    unmap_values,
)
from brdfcodec.representation.mask import horizon_mask

if TYPE_CHECKING:
    pass


__all__ = ["ClampWarning", "MaskedEntries", "prepare_source", "resolve_model"]


MaskedEntries = Literal["unmeasured", "zero", "keep"]
ModelSpec = str | os.PathLike[str] | ModelManifest | None


def resolve_model(model: ModelSpec) -> ModelManifest:
    """A model's manifest from a manifest (returned as it is), or from what
    :func:`~brdfcodec.models.registry.resolve_manifest` takes: a model folder, a decoder SHA-256 (64 hex digits,
    or the first 16 that a file with short references names, format 2.6), the name of a findable model (its
    folder's name, such as ``"editing"`` for the opt-in editing model, or the name its ``model.json`` gives;
    ``"default"`` is the shipped default), or ``None`` for the shipped default.

    Raises
    ------
    DecoderNotFoundError
        A hash or a name that no findable model has (:class:`~brdfcodec.errors.ModelNotFoundError`; the message
        lists the available ones).
    ModelFolderError
        A path that is not a valid model folder.
    """
    if isinstance(model, ModelManifest):
        return model
    return resolve_manifest(model)


class ClampWarning(UserWarning):
    """A source table held values beyond the range the codec represents; they were clamped (the message says how
    many)."""


def _stored_limit() -> np.ndarray:
    """Largest stored value per channel the codec represents: the inverse mapping of ``MAPPED_MAX``."""
    return unmap_values(np.full(3, MAPPED_MAX, dtype=np.float64))


def prepare_source(brdf: MerlBRDF, *, warn: bool = True) -> MerlBRDF:
    """A table ready for encoding and measuring: refused if nothing is measured, clamped to the codec's range.

    A black table (all 0) is a valid material and passes unchanged. Stored
    values whose mapping exceeds ``MAPPED_MAX`` (about 1.05e8 /sr of
    reflectance) are clamped to that value, with a :class:`ClampWarning`
    saying how many entries and by how much; the table's SHA-256 stays that
    of its source.

    Raises
    ------
    UnmeasuredMaterialError
        No entry above the horizon is measured (all negative).
    """
    where = os.fspath(brdf.path) if brdf.path is not None else (brdf.name or "<table>")
    if not brdf.mask.any():
        raise UnmeasuredMaterialError(
            where, "no measured entry above the horizon (every value is negative, MERL's 'unmeasured'): "
            "there is nothing to compress"
        )
    limit = _stored_limit().reshape(3, 1, 1, 1)
    over = brdf.values > limit  # below-horizon entries too: nothing downstream may overflow
    if not over.any():
        return brdf
    count = int(np.count_nonzero(over & brdf.mask))
    if warn and count:
        largest = float((brdf.values / limit)[over & brdf.mask].max())
        warnings.warn(
            f"{where}: {count} of {int(np.count_nonzero(brdf.mask))} measured entries exceed the largest value "
            f"the codec represents (mapped {MAPPED_MAX:g}, about 1.05e8 /sr), by up to {largest:.3g}x; "
            "they were clamped to it",
            ClampWarning,
            stacklevel=2,
        )
    clamped = np.where(over, np.broadcast_to(limit, brdf.values.shape), brdf.values)
    return replace(brdf, values=clamped, _file_sha256=brdf.sha256)  # provenance kept: name, path, source


@functools.cache
def _invalid_bins() -> np.ndarray:
    """Below-horizon bins of one channel, shape (90, 90, 180)."""
    invalid = ~horizon_mask()
    invalid.setflags(write=False)
    return invalid




def _apply_mask(table: np.ndarray, bins: Sequence[int] | None, masked: MaskedEntries) -> np.ndarray:
    if masked == "keep":
        return table
    if masked not in ("unmeasured", "zero"):
        raise ValueError(f"masked must be 'unmeasured', 'zero' or 'keep', got {masked!r}")
    invalid = _invalid_bins() if bins is None else _invalid_bins()[..., list(bins)]
    fill = UNMEASURED_VALUE if masked == "unmeasured" else 0.0
    np.copyto(table, np.float32(fill), where=np.broadcast_to(invalid, table.shape))
    return table


