"""Rate–distortion operating points of the report (issue 14): layered brdfcodec and fairly packed baselines.

Every point here is evaluated on the held-out materials only
(``held_out_only``): the question it answers is "at N bytes per material,
which codec is better on materials it has not seen". Points of one family
(``family``) form one curve of the rate–distortion plots.

- ``bvae-layered@N``: the shipped β-VAE, float16 latents, effort 1, and the
  enhancement layers rate control chooses within N bytes of record payload:
  coefficients on the model's shared basis (compact σ; below the size that
  holds all of them, a compact base: μ as int8, one σ byte), then a detail
  layer; in records without a detail layer, the base decode projected on the
  shared basis (format 1.6) where, measured on the material, that lowers its
  error (``--project-base auto``, the default);
- ``bvae-max-relae-X``: the same with ``--max-relae X`` (the smallest tried
  record meeting X on each material);
- ``bvae-projected@N`` and ``bvae-unprojected@N``: the same as
  ``bvae-layered@N`` with the base decode always projected
  (``--project-base always``) or never (``never``), up to 256 B, where the
  basis layer is what the bytes buy: what the per-material choice gains;
- ``pca-k-float16`` / ``pca-k-int8``: PCA of the mapped kept slices (basis of
  the training split), coefficients (orthogonal projection) as float16, or
  as int8 with one float16 scale per material (k + 2 bytes; also k = 14, 30
  and 62, which fill 16 B, 32 B and 64 B exactly);
- ``pca-perm-k-float16`` / ``pca-perm-k-int8``: the same PCA fitted on the
  training materials in all 6 orders of their colour channels (up to its
  rank, 5N − 1 coefficients: 379 for 76 materials), a stronger baseline than
  PCA of the materials as measured, since it spans colours the training
  set lacks (documentation: Results);
- ``zstd-slices@Δ``: the mapped kept slices quantised at step Δ, int16,
  zstandard level 19 (the plain "quantise and zip" codec);
- ``dct-slices@Δ``: the detail layer's own coder (colour decorrelation, 3-D
  DCT, step Δ, zstandard) on the kept slices with no β-VAE base: the
  ablation that says what the base is worth.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from brdfcodec.conventions import MAPPED_MAX
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.report.points import Material, OperatingPoint
from brdfcodec.representation import table_from_network_output

if TYPE_CHECKING:
    from brdfcodec.codec.encoding import ProjectBase

__all__ = ["rate_distortion_points"]

#: Payload budgets of the layered points, bytes per material.
LAYERED_BUDGETS = (16, 32, 64, 128, 256, 1024, 4096, 16384, 65536, 262144)
#: Payload budgets of the points whose base is always, or never, projected (the encoder's choice made fixed).
PROJECTED_BUDGETS = (16, 32, 64, 128, 256)


def _size_label(n: int) -> str:
    return f"{n // 1024}KB" if n >= 1024 and n % 1024 == 0 else f"{n}B"


class LayeredBvae(OperatingPoint):
    """The shipped β-VAE with refinement and a rate-controlled detail layer (float16 latents)."""

    held_out_only = True
    family = "bvae-layered"

    def __init__(self, *, bytes_budget: int | None = None, max_relae: float | None = None, model: Any = None,
                 project_base: ProjectBase = "auto") -> None:
        from brdfcodec.codec import BrdfEncoder

        self.encoder = BrdfEncoder(model, effort=1, bytes=bytes_budget, max_relae=max_relae, latent_dtype="float16",
                                   project_base=project_base)
        self.decoder = self.encoder.decoder
        if project_base != "auto":
            if bytes_budget is None:
                raise ValueError(f"a point with project_base={project_base!r} needs a size budget")
            self.family = "bvae-projected" if project_base == "always" else "bvae-unprojected"
            self.name = f"{self.family}@{_size_label(bytes_budget)}"
            how = ("projected on the shared basis (--project-base always)" if project_base == "always" else
                   "never projected (--project-base never)")
            self.description = (f"β-VAE (effort 1, float16) + basis layer over the base {how}, at most "
                                f"{bytes_budget} B of payload")
        elif bytes_budget is not None:
            self.name = f"bvae-layered@{_size_label(bytes_budget)}"
            self.description = (
                f"β-VAE (effort 1, float16) + basis and detail layers (the base projected where that lowers the "
                f"error, the default), at most {bytes_budget} B of payload"
            )
        else:
            self.family = f"bvae-max-relae-{max_relae:g}"
            self.name = self.family
            self.description = (
                f"β-VAE (effort 1, float16) + detail layer, smallest tried record with RelAE ≤ {max_relae}"
            )

    def shared_bytes(self) -> int:
        folder = self.decoder.manifest.folder
        files = ["decoder.safetensors", *(["basis.safetensors"] if self.decoder.manifest.basis_sha256 else [])]
        return sum(int((folder / name).stat().st_size) for name in files)

    def encode(self, material: Material) -> bytes:
        from brdfcodec.format.bvae import encode_bvae

        source = MerlBRDF(np.where(material.mask, material.values, -1.0), name=material.name)
        record = self.encoder.encode_arrays(
            [material.name], material.inputs[None], _input_mask(material)[None], [source]
        )[0]
        return encode_bvae([record], self.decoder.reference, latent_dtype="float16")

    def payload_bytes(self, payload: bytes) -> int:
        from brdfcodec.format.bvae import parse_bvae

        return parse_bvae(payload).header.entries[0].length

    def decode(self, payload: bytes) -> np.ndarray:
        from brdfcodec.format.bvae import parse_bvae

        return self.decoder.decode(parse_bvae(payload).records[0], masked="keep").astype(np.float64)


def _input_mask(material: Material) -> np.ndarray:
    from brdfcodec.representation import select_kept_slices, to_network_layout

    return to_network_layout(select_kept_slices(material.mask))


class PcaPacked(OperatingPoint):
    """PCA-k of the mapped kept slices with float16 or int8 (+ a float16 scale) coefficients.

    ``variant`` names a PCA fitted on other data than the training materials as measured (``"perm"``: with
    their colour permutations); it goes into the point's name and family.
    """

    held_out_only = True

    def __init__(self, basis: Any, k: int, storage: str, variant: str = "") -> None:
        self.basis, self.k, self.storage = basis, k, storage
        prefix = f"pca-{variant}" if variant else "pca"
        self.family = f"{prefix}-{storage}"
        self.name = f"{prefix}-{k}-{storage}"
        fitted = " (fitted on the training materials in all 6 colour orders)" if variant == "perm" else ""
        self.description = f"PCA of mapped kept slices{fitted}, {k} coefficients as {storage}" + (
            " with one float16 scale per material" if storage == "int8" else ""
        )

    def shared_bytes(self) -> int:
        return int(self.basis.mean.nbytes + self.basis.components[: self.k].nbytes)

    def encode(self, material: Material) -> bytes:
        c = (material.inputs.reshape(-1) - self.basis.mean) @ self.basis.components[: self.k].T
        if self.storage == "float16":
            return c.astype("<f2").tobytes()
        scale = np.float16(max(float(np.abs(c).max()), 1e-6) / 127.0)
        q = np.clip(np.rint(c / np.float32(scale)), -127, 127).astype(np.int8)
        return scale.tobytes() + q.tobytes()

    def payload_bytes(self, payload: bytes) -> int:
        return len(payload)

    def decode(self, payload: bytes) -> np.ndarray:
        if self.storage == "float16":
            c = np.frombuffer(payload, dtype="<f2").astype(np.float32)
        else:
            scale = np.frombuffer(payload[:2], dtype="<f2").astype(np.float32)[0]
            c = np.frombuffer(payload[2:], dtype=np.int8).astype(np.float32) * scale
        mapped = np.clip(c @ self.basis.components[: self.k] + self.basis.mean, 0.0, MAPPED_MAX)
        return table_from_network_output(mapped.reshape(63, 90, 90)).astype(np.float64)


class ZstdSlices(OperatingPoint):
    """Mapped kept slices quantised at step Δ (int16) and packed with zstandard (level 19)."""

    held_out_only = True
    family = "zstd-slices"

    def __init__(self, step: float) -> None:
        self.step = step
        self.name = f"zstd-slices@{step:g}"
        self.description = f"mapped kept slices, step {step:g}, int16, zstandard level 19"

    def encode(self, material: Material) -> bytes:
        import zstandard

        q = np.rint(material.inputs / self.step).astype("<i2")
        return zstandard.ZstdCompressor(level=19).compress(q.tobytes())

    def payload_bytes(self, payload: bytes) -> int:
        return len(payload)

    def decode(self, payload: bytes) -> np.ndarray:
        import zstandard

        q = np.frombuffer(zstandard.ZstdDecompressor().decompress(payload), dtype="<i2")
        return table_from_network_output((q * np.float32(self.step)).reshape(63, 90, 90)).astype(np.float64)


class DctSlices(OperatingPoint):
    """The detail layer's coder on the kept slices themselves (no β-VAE base): the ablation."""

    held_out_only = True
    family = "dct-slices"

    def __init__(self, step: float) -> None:
        self.step = step
        self.name = f"dct-slices@{step:g}"
        self.description = f"colour + 3-D DCT of the mapped kept slices, step {step:g}, zstandard (no β-VAE)"

    def encode(self, material: Material) -> bytes:
        from brdfcodec.layers.detail import encode_detail

        return encode_detail(material.inputs, self.step).data

    def payload_bytes(self, payload: bytes) -> int:
        return len(payload)

    def decode(self, payload: bytes) -> np.ndarray:
        from brdfcodec.layers.detail import DetailLayer, decode_detail

        dtype = "int16"
        try:
            mapped = decode_detail(DetailLayer(float(self.step), dtype, payload))
        except ValueError:
            mapped = decode_detail(DetailLayer(float(self.step), "int32", payload))
        return table_from_network_output(mapped.reshape(63, 90, 90)).astype(np.float64)


def rate_distortion_points(train_inputs: np.ndarray, model: Any = None) -> list[OperatingPoint]:
    """The report's rate–distortion points (held-out materials only)."""
    from brdfcodec.layers.basis import shared_basis_rank
    from brdfcodec.models.pca import fit_pca, fit_pca_colour_orders

    points: list[OperatingPoint] = [LayeredBvae(bytes_budget=n, model=model) for n in LAYERED_BUDGETS]
    points.append(LayeredBvae(max_relae=0.02, model=model))
    points += [LayeredBvae(bytes_budget=n, model=model, project_base=way) for n in PROJECTED_BUDGETS
               for way in ("always", "never")]
    basis = fit_pca(train_inputs, min(75, len(train_inputs)))
    sizes = [k for k in (8, 16, 32, 64, 75) if k <= basis.n_components]
    points += [PcaPacked(basis, k, "float16") for k in sizes]
    # int8 also at k = N − 2, so that each budget of the comparison (16 B, 32 B, 64 B) is filled exactly.
    int8_sizes = sorted({*sizes, *(k for k in (14, 30, 62) if k <= basis.n_components)})
    points += [PcaPacked(basis, k, "int8") for k in int8_sizes]
    # The same PCA fitted on the training materials in all 6 orders of their colour channels: the stronger
    # baseline, since the basis then spans colours the training set lacks (as the basis layer's own can).
    # Up to its rank (5N − 1), so that it is as good as PCA can be within 1 KB too (379 int8 coefficients: 381 B).
    rank = shared_basis_rank(len(train_inputs), colour_permutations=True)
    permuted = fit_pca_colour_orders(train_inputs, min(rank, 512))
    points += [PcaPacked(permuted, k, "float16", "perm") for k in (8, 16, 32, 64, 128, 256, 512) if k <= rank]
    int8_counts = sorted({k for k in (14, 30, 62, 126, 254, 510) if k <= rank} | {min(rank, 510)})
    points += [PcaPacked(permuted, k, "int8", "perm") for k in int8_counts]
    points += [ZstdSlices(step) for step in (0.004, 0.016, 0.064, 0.25, 1.0)]
    points += [DctSlices(step) for step in (0.01, 0.04, 0.16, 0.64, 2.56, 10.24)]
    return points
