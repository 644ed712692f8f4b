"""Operating points of the size / error / time report: the codec and the alternatives a user would pick instead.

Each point turns one material (its stored table and network input) into a
payload and back into a full table in stored MERL units, and says how many
bytes a material costs and how many are shared by all materials (a decoder,
a basis). Encode and decode are timed by the caller around
:meth:`OperatingPoint.encode` and :meth:`OperatingPoint.decode`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from brdfcodec.conventions import TABLE_SHAPE
from brdfcodec.representation import (
    interpolate_slices,
    map_values,
    select_kept_slices,
    table_from_network_output,
    unmap_values,
)

__all__ = ["Material", "OperatingPoint", "standard_points"]


@dataclass(frozen=True)
class Material:
    """What the points get of one material: stored table (float64), its mask, and the network input."""

    name: str
    values: np.ndarray
    mask: np.ndarray
    inputs: np.ndarray
    split: str


class OperatingPoint:
    """Base class: a way to store one material."""

    name = "base"
    description = ""
    lossless = False

    def shared_bytes(self) -> int:
        """Bytes every material shares (model weights, basis); 0 if none."""
        return 0

    def encode(self, material: Material) -> Any:
        """The payload of a material."""
        raise NotImplementedError

    def payload_bytes(self, payload: Any) -> int:
        """Bytes of one payload."""
        raise NotImplementedError

    def decode(self, payload: Any) -> np.ndarray:
        """Full table (3, 90, 90, 180) in stored units (invalid entries may hold anything)."""
        raise NotImplementedError


class RawTable(OperatingPoint):
    """The table itself as float32 or float16 (float16 saturates at 65504 stored units)."""

    def __init__(self, dtype: str) -> None:
        self.dtype = np.dtype(dtype)
        self.name = f"raw-{dtype}"
        self.description = f"the full table as {dtype}"

    def encode(self, material: Material) -> bytes:
        finite_max = np.finfo(self.dtype).max
        return np.clip(material.values, -finite_max, finite_max).astype(self.dtype).tobytes()

    def payload_bytes(self, payload: bytes) -> int:
        return len(payload)

    def decode(self, payload: bytes) -> np.ndarray:
        return np.frombuffer(payload, dtype=self.dtype).astype(np.float64).reshape(TABLE_SHAPE)


class ZstdTable(RawTable):
    """zstandard over the raw float32 / float16 bytes (lossless with respect to that dtype)."""

    def __init__(self, dtype: str, level: int = 3) -> None:
        super().__init__(dtype)
        self.level = level
        self.name = f"zstd-{dtype}"
        self.description = f"zstandard (level {level}) over the {dtype} table"
        self.lossless = dtype == "float32"

    def encode(self, material: Material) -> bytes:
        import zstandard

        return zstandard.ZstdCompressor(level=self.level).compress(super().encode(material))

    def decode(self, payload: bytes) -> np.ndarray:
        import zstandard

        return super().decode(zstandard.ZstdDecompressor().decompress(payload))


class KeptSlices(OperatingPoint):
    """The 21 kept φd slices in float32, interpolated back in the mapped domain: the slice scheme's error floor."""

    name = "kept-slices"
    description = "the 21 kept φd slices (float32) + interpolation, no network"

    def encode(self, material: Material) -> np.ndarray:
        return select_kept_slices(np.where(material.mask, material.values, 0.0)).astype(np.float32)

    def payload_bytes(self, payload: np.ndarray) -> int:
        return int(payload.nbytes)

    def decode(self, payload: np.ndarray) -> np.ndarray:
        return unmap_values(interpolate_slices(map_values(payload)))


class Pca(OperatingPoint):
    """PCA of the mapped kept slices (the classic data-driven baseline), k float32 coefficients per material."""

    def __init__(self, train_inputs: np.ndarray, k: int) -> None:
        from brdfcodec.models.pca import fit_pca

        self.basis = fit_pca(train_inputs, k)
        self.k = k
        self.name = f"pca-{k}"
        self.description = f"PCA of mapped kept slices, {k} coefficients (basis fitted on the training split)"

    def shared_bytes(self) -> int:
        return int(self.basis.mean.nbytes + self.basis.components.nbytes)

    def encode(self, material: Material) -> np.ndarray:
        return self.basis.encode(material.inputs[None])[0].astype(np.float32)

    def payload_bytes(self, payload: np.ndarray) -> int:
        return int(payload.nbytes)

    def decode(self, payload: np.ndarray) -> np.ndarray:
        return table_from_network_output(self.basis.decode(payload[None])[0]).astype(np.float64)


class BvaeCodec(OperatingPoint):
    """The shipped β-VAE: a .bvae latent record (μ, σ) per material, decoded by the shared decoder."""

    def __init__(self, latent_dtype: str = "float32", model: Any = None) -> None:
        from brdfcodec.codec import BrdfDecoder, BrdfEncoder

        self.encoder = BrdfEncoder(model)
        self.decoder = BrdfDecoder(self.encoder.manifest)
        self.latent_dtype = latent_dtype
        model_name = self.decoder.manifest.name
        self.name = f"{model_name if model_name.startswith('bvae') else 'bvae-' + model_name}-{latent_dtype}"
        self.description = (
            f"β-VAE latent record, {latent_dtype} latents ({self.decoder.manifest.name}); bytes = record payload, "
            "the .bvae header adds about 11 B per material in a library of 100"
        )

    def shared_bytes(self) -> int:
        return int((self.decoder.manifest.folder / "decoder.safetensors").stat().st_size)

    def encode(self, material: Material) -> bytes:
        from brdfcodec.format.bvae import LatentRecord, encode_bvae

        mu, sigma = self.encoder.posterior_from_inputs(material.inputs[None])
        record = LatentRecord(material.name, mu[0], sigma[0])
        return encode_bvae([record], self.decoder.reference, latent_dtype=self.latent_dtype)  # type: ignore[arg-type]

    def payload_bytes(self, payload: bytes) -> int:
        """The record's payload (64 B for 8 float32 μ and σ): what a material adds to a library.

        The file's header (decoder reference, index) comes on top: shared by every material of a library, so
        it weighs far more on a file of one (documentation: The .bvae format, Sizes).
        """
        from brdfcodec.format.bvae import parse_bvae

        return parse_bvae(payload).header.entries[0].length

    def decode(self, payload: bytes) -> np.ndarray:
        from brdfcodec.format.bvae import parse_bvae

        record = parse_bvae(payload).records[0]
        return self.decoder.decode(record, masked="keep").astype(np.float64)


def standard_points(
    train_inputs: np.ndarray,
    pca_sizes: Sequence[int] = (8, 16, 32),
    extra_models: Sequence[Any] = (),
) -> list[OperatingPoint]:
    """The report's operating points: the shipped model (float32, float16 latents), other models, every baseline.

    The rate–distortion points (:func:`brdfcodec.report.rd_points.rate_distortion_points`) are added by the
    caller, :func:`brdfcodec.report.evaluate.evaluate_dataset`.
    """
    points: list[OperatingPoint] = [BvaeCodec("float32"), BvaeCodec("float16")]
    points += [BvaeCodec("float32", model) for model in extra_models]
    points += [Pca(train_inputs, k) for k in pca_sizes if k <= len(train_inputs)]
    points += [KeptSlices(), RawTable("float32"), RawTable("float16"), ZstdTable("float32"), ZstdTable("float16")]
    return points
