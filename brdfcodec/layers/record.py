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
from brdfcodec.hashing import is_sha256_hex
from brdfcodec.layers.basis import MAX_BASIS_COUNT, STEP_BYTES, BasisLayer, basis_layer_from_bytes
from brdfcodec.layers.detail import _DTYPES, DETAIL_TRANSFORM, MAX_STEP, MIN_STEP, N_DETAIL_VALUES, DetailLayer

__all__ = [
    "LAYERED_KIND",
    "SIGMA_LOG2_U8",
    "LayeredRecord",
    "latent_values_stored",
    "layered_from_payload",
    "layers_entry",
    "layers_length",
    "quantise_sigma",
    "sigma_from_codes",
]

#: Record kind of a layered record in the index (``kind`` field).
LAYERED_KIND = "layered"
#: Largest detail layer a record may declare, in bytes (the raw float32 kept slices are 2 MB).
MAX_DETAIL_BYTES = 64 << 20
#: ``layers.sigma`` of a record that stores σ as one byte per dimension: σ = 2^(q/16 − 12), q in 0…255.
SIGMA_LOG2_U8 = "log2-u8"
_SIGMA_LOG2_MIN, _SIGMA_STEPS_PER_OCTAVE = -12.0, 16.0


def quantise_sigma(sigma: np.ndarray) -> np.ndarray:
    """One byte per posterior width: ``round(16 · (log2 σ + 12))`` clipped to 0…255 (σ within 2.2 %)."""
    log2 = np.log2(np.maximum(np.asarray(sigma, dtype=np.float64), 1e-30))
    return np.clip(np.rint((log2 - _SIGMA_LOG2_MIN) * _SIGMA_STEPS_PER_OCTAVE), 0, 255).astype(np.uint8)


def sigma_from_codes(codes: np.ndarray) -> np.ndarray:
    """Inverse of :func:`quantise_sigma`: σ = 2^(q/16 − 12), float32 (exact for every code)."""
    return np.exp2(np.asarray(codes, dtype=np.float64) / _SIGMA_STEPS_PER_OCTAVE + _SIGMA_LOG2_MIN).astype(np.float32)


@dataclass(frozen=True)
class LayeredRecord(LatentRecord):
    """A base latent record plus enhancement layers: a basis layer, a detail layer, or both.

    Attributes
    ----------
    name, mu, sigma, meta
        As in :class:`~brdfcodec.bvae_format.LatentRecord`: ``mu`` is the
        base code (refined at encode time, see ``spec/bvae-format.md`` §4.4),
        ``sigma`` the encoder's posterior width.
    detail : DetailLayer or None
        The residual of the kept slices left by decoding ``mu`` and the basis layer.
    basis : BasisLayer or None
        Coefficients on the model's shared basis.
    compact_sigma : bool
        Store σ as one byte per dimension (``layers.sigma = "log2-u8"``, within 2.2 %) instead of in the
        file's latent dtype. ``sigma`` then holds the stored (quantised) widths.
    """

    detail: DetailLayer | None = None
    kind: Literal["layered"] = field(default="layered", init=False)  # type: ignore[assignment]
    basis: BasisLayer | None = None
    compact_sigma: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.detail is None and self.basis is None:
            raise ValueError(f"{self.name}: a layered record needs a basis layer, a detail layer or both")
        if self.detail is not None and not isinstance(self.detail, DetailLayer):
            raise ValueError(f"{self.name}: detail must be a DetailLayer, got {type(self.detail).__name__}")
        if self.basis is not None and not isinstance(self.basis, BasisLayer):
            raise ValueError(f"{self.name}: basis must be a BasisLayer, got {type(self.basis).__name__}")
        if self.compact_sigma:  # what is stored is what the record holds, so writing and reading agree
            object.__setattr__(self, "sigma", sigma_from_codes(quantise_sigma(self.sigma)))

    def payload_values(self) -> np.ndarray:
        """Values stored in the latent dtype: ``mu`` and, unless σ is compact, ``sigma``."""
        return np.array(self.mu) if self.compact_sigma else super().payload_values()

    def base(self) -> LatentRecord:
        """The base alone (what edits act on): a plain latent record with the same μ, σ and meta."""
        return LatentRecord(self.name, self.mu, self.sigma, self.meta)

    def layer_bytes(self) -> bytes:
        """The bytes that follow the latent values: compact σ, the basis layer's, then the detail layer's."""
        sigma = quantise_sigma(self.sigma).tobytes() if self.compact_sigma else b""
        return (sigma + (b"" if self.basis is None else self.basis.data)
                + (b"" if self.detail is None else self.detail.data))


def layers_entry(record: LayeredRecord) -> dict[str, Any]:
    """The ``layers`` object of a layered record's index entry."""
    entry: dict[str, Any] = {}
    if record.compact_sigma:
        entry["sigma"] = SIGMA_LOG2_U8
    if record.basis is not None:
        entry["basis"] = record.basis.entry()
    if record.detail is not None:
        entry["detail"] = record.detail.entry()
    return entry


def latent_values_stored(layers: Mapping[str, Any], latent_dim: int) -> int:
    """Values a layered record stores in the latent dtype (its ``layers`` already validated): D or 2·D."""
    return latent_dim if layers.get("sigma") == SIGMA_LOG2_U8 else 2 * latent_dim


def layers_length(layers: object, where: str, latent_dim: int = 0) -> int:
    """Validate an index entry's ``layers`` object and return the bytes its layers (and compact σ) take.

    Raises
    ------
    ValueError
        Missing or malformed fields (the message says which); the caller wraps it in a format error.
    UnsupportedLayerError
        A layer or transform this reader does not know.
    """
    if not isinstance(layers, Mapping):
        raise ValueError(f"{where} field 'layers' is not a JSON object")
    unknown = sorted(set(layers) - {"basis", "detail", "sigma"})
    if unknown:
        raise UnsupportedLayerError(f"{where} has layers {unknown}, unknown to this reader; upgrade brdfcodec")
    if "basis" not in layers and "detail" not in layers:
        raise ValueError(f"{where} layers hold neither 'basis' nor 'detail'")
    length = 0
    if "sigma" in layers:
        if layers["sigma"] != SIGMA_LOG2_U8:
            raise UnsupportedLayerError(
                f"{where} stores sigma as {layers['sigma']!r}, unknown to this reader ({SIGMA_LOG2_U8}); "
                "upgrade brdfcodec"
            )
        length += latent_dim
    if "basis" in layers:
        length += _basis_length(layers["basis"], where)
    if "detail" in layers:
        length += _detail_length(layers["detail"], where)
    return length


def _basis_length(basis: object, where: str) -> int:
    if not isinstance(basis, Mapping):
        raise ValueError(f"{where} layers.basis is not a JSON object")
    unknown = sorted(set(basis) - {"sha256", "count", "first"})
    if unknown:
        raise UnsupportedLayerError(
            f"{where} basis layer has fields {unknown}, unknown to this reader; upgrade brdfcodec"
        )
    sha, count, first = basis.get("sha256"), basis.get("count"), basis.get("first", 0)
    if not is_sha256_hex(sha):
        raise ValueError(f"{where} basis sha256 {sha!r} is not 64 lower-case hex digits")
    if not isinstance(count, int) or isinstance(count, bool) or not 1 <= count <= MAX_BASIS_COUNT:
        raise ValueError(f"{where} basis count {count!r} is not an integer in [1, {MAX_BASIS_COUNT}]")
    if not isinstance(first, int) or isinstance(first, bool) or not 0 <= first <= MAX_BASIS_COUNT - count:
        raise ValueError(
            f"{where} basis first {first!r} is not an integer in [0, {MAX_BASIS_COUNT} − count]"
        )
    return STEP_BYTES + count


def _detail_length(detail: object, where: str) -> int:
    if not isinstance(detail, Mapping):
        raise ValueError(f"{where} layers.detail is not a JSON object")
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

    compact = layers.get("sigma") == SIGMA_LOG2_U8
    if compact:
        sigma = sigma_from_codes(np.frombuffer(tail[: len(mu)], dtype=np.uint8))
        tail = tail[len(mu) :]
    basis = None
    if "basis" in layers:
        size = STEP_BYTES + int(layers["basis"]["count"])
        basis = basis_layer_from_bytes(layers["basis"], bytes(tail[:size]))
        tail = tail[size:]
    if "detail" not in layers:
        return LayeredRecord(name, mu, sigma, meta, basis=basis, compact_sigma=compact)
    detail = layers["detail"]
    layer = DetailLayer(float(detail["step"]), str(detail["dtype"]), bytes(tail))
    expected = N_DETAIL_VALUES * _DTYPES[layer.dtype].itemsize
    try:
        declared = zstandard.get_frame_parameters(layer.data).content_size
    except zstandard.ZstdError as error:
        raise ValueError(f"detail layer is not a zstandard frame ({error})") from None
    if declared != expected:
        raise ValueError(f"detail layer declares {declared} bytes of content, expected {expected}")
    return LayeredRecord(name, mu, sigma, meta, detail=layer, basis=basis, compact_sigma=compact)
