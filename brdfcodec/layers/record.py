"""Layered records: the β-VAE latent (the base) plus enhancement layers (``spec/bvae-format.md`` §4.4).

A :class:`LayeredRecord` is a :class:`~brdfcodec.bvae_format.LatentRecord`
(so everything that reads a base latent — edits, parameters, the decoder's
base path — works on it unchanged) that also carries a
:class:`~brdfcodec.layers.detail.DetailLayer`. This module holds the
format's view of the layers: the index-entry object, the payload bytes, and
their validation when a file is read. It does not import torch.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from brdfcodec.bvae_format import LatentRecord
from brdfcodec.layers.detail import _DTYPES, DETAIL_TRANSFORM, MAX_STEP, MIN_STEP, N_DETAIL_VALUES, DetailLayer

__all__ = ["LAYERED_KIND", "LayeredRecord", "layered_from_payload", "layers_entry", "layers_length"]

#: Record kind of a layered record in the index (``kind`` field).
LAYERED_KIND = "layered"
#: Largest detail layer a record may declare, in bytes (the raw float32 kept slices are 2 MB).
MAX_DETAIL_BYTES = 64 << 20


@dataclass(frozen=True)
class LayeredRecord(LatentRecord):
    """A base latent record plus a detail layer.

    Attributes
    ----------
    name, mu, sigma, meta
        As in :class:`~brdfcodec.bvae_format.LatentRecord`: ``mu`` is the
        base code (refined at encode time, see ``spec/bvae-format.md`` §4.4),
        ``sigma`` the encoder's posterior width.
    detail : DetailLayer
        The residual of the kept slices left by decoding ``mu``.
    """

    detail: DetailLayer | None = None
    kind: Literal["layered"] = field(default="layered", init=False)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.detail, DetailLayer):
            raise ValueError(f"{self.name}: a layered record needs a DetailLayer, got {type(self.detail).__name__}")

    def base(self) -> LatentRecord:
        """The base alone (what edits act on): a plain latent record with the same μ, σ and meta."""
        return LatentRecord(self.name, self.mu, self.sigma, self.meta)

    def layer_bytes(self) -> bytes:
        """The bytes that follow μ and σ in the payload."""
        assert self.detail is not None
        return self.detail.data


def layers_entry(record: LayeredRecord) -> dict[str, Any]:
    """The ``layers`` object of a layered record's index entry."""
    assert record.detail is not None
    return {"detail": record.detail.entry()}


def layers_length(layers: object, where: str) -> int:
    """Validate an index entry's ``layers`` object and return the bytes its layers take.

    Raises
    ------
    ValueError
        Missing or malformed fields (the message says which); the caller wraps it in a format error.
    UnsupportedLayerError
        A layer or transform this reader does not know.
    """
    if not isinstance(layers, Mapping):
        raise ValueError(f"{where} field 'layers' is not a JSON object")
    unknown = sorted(set(layers) - {"detail"})
    if unknown:
        raise UnsupportedLayerError(f"{where} has layers {unknown}, unknown to this reader; upgrade brdfcodec")
    detail = layers.get("detail")
    if not isinstance(detail, Mapping):
        raise ValueError(f"{where} layers lack a 'detail' object")
    transform = detail.get("transform")
    if transform != DETAIL_TRANSFORM:
        raise UnsupportedLayerError(
            f"{where} detail transform {transform!r} is unknown to this reader ({DETAIL_TRANSFORM}); upgrade brdfcodec"
        )
    step, dtype, length = detail.get("step"), detail.get("dtype"), detail.get("length")
    if not isinstance(step, float | int) or isinstance(step, bool) or not MIN_STEP <= float(step) <= MAX_STEP:
        raise ValueError(f"{where} detail step {step!r} is not a number in [{MIN_STEP}, {MAX_STEP}]")
    if dtype not in _DTYPES:
        raise ValueError(f"{where} detail dtype {dtype!r} is not one of {sorted(_DTYPES)}")
    if not isinstance(length, int) or isinstance(length, bool) or not 1 <= length <= MAX_DETAIL_BYTES:
        raise ValueError(f"{where} detail length {length!r} is not an integer in [1, {MAX_DETAIL_BYTES}]")
    return length


class UnsupportedLayerError(ValueError):
    """A layer kind or transform that this reader does not implement (mapped to UnsupportedVersionError)."""


def layered_from_payload(
    name: str, mu: np.ndarray, sigma: np.ndarray, layers: Mapping[str, Any], tail: bytes, meta: Mapping[str, Any]
) -> LayeredRecord:
    """A layered record from its validated entry and the payload bytes after μ and σ."""
    import zstandard

    detail = layers["detail"]
    layer = DetailLayer(float(detail["step"]), str(detail["dtype"]), bytes(tail))
    expected = N_DETAIL_VALUES * _DTYPES[layer.dtype].itemsize
    try:
        declared = zstandard.get_frame_parameters(layer.data).content_size
    except zstandard.ZstdError as error:
        raise ValueError(f"detail layer is not a zstandard frame ({error})") from None
    if declared != expected:
        raise ValueError(f"detail layer declares {declared} bytes of content, expected {expected}")
    return LayeredRecord(name, mu, sigma, meta, detail=layer)
