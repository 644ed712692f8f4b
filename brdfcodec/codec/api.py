"""The codec: MERL tables to ``.bvae`` bytes and back.

Two inverse functions on bytes, the shape codec libraries have::

    data = encode(brdfs)            # MerlBRDF objects or MERL file paths -> bytes of a .bvae file
    library = decode(data)          # bytes -> MaterialLibrary (name -> DecodedMaterial, decoded lazily)

and file helpers on top: :func:`compress` writes ``encode(...)`` atomically,
:func:`decompress` reads one material's table from a file. ``bvae compress``
calls :func:`encode_records`, the loop underneath :func:`encode`.

:class:`BrdfEncoder` and :class:`BrdfDecoder` hold a loaded network and its
device and are meant to be reused; they are the only code that runs the
networks in batches (training evaluation, export, the report and the named
parameters use them too, through :meth:`BrdfDecoder.from_network` for a
network in memory). :class:`MaterialLibrary` opens a ``.bvae`` file (or
bytes) and decodes a material only when it is first used, so a scene that
uses 3 materials of a library of 100 decodes 3.

Decoded tables follow ``spec/bvae-format.md`` §6: stored MERL units
(:func:`brdfcodec.representation.reflectance_from_stored` gives 1/sr),
float32, and entries whose bin lies below the horizon set to ``-1``
(unmeasured) unless asked otherwise.
"""

from __future__ import annotations

import functools
import itertools
import os
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.conventions import MAPPED_MAX, N_KEPT_SLICES, NETWORK_INPUT_SHAPE, UNMEASURED_VALUE
from brdfcodec.errors import (
    BasisMismatchError,
    DecoderMismatchError,
    DecoderNotFoundError,
    LatentDimensionError,
    UnmeasuredMaterialError,
)
from brdfcodec.format.bvae import (
    BvaeHeader,
    BvaeReader,
    DecoderReference,
    GraftRecord,
    LatentDtype,
    LatentRecord,
    Record,
    encode_bvae,
    parse_bvae,
    without_provenance,
)
from brdfcodec.io.atomic import atomic_output, check_output_path
from brdfcodec.io.inputs import read_measured
from brdfcodec.io.merl import MerlBRDF, source_digest
from brdfcodec.models.registry import default_model_folder, find_model
from brdfcodec.models.store import ModelManifest, load_manifest, load_model
from brdfcodec.representation import (
    GREEN_BLOCK,
    RED_BLOCK,
    clamp_mapped,
    kept_slots_for_bins,
    network_channels_for_slots,
    network_input_from_table,
    reflectance_from_mapped,
    table_from_mapped,
    to_network_layout,
    unmap_values,
    validate_phi_d_bins,
)
from brdfcodec.representation.mask import horizon_mask, kept_slice_horizon_mask
from brdfcodec.representation.metrics import relae_both
from brdfcodec.runtime.threads import codec_threads

if TYPE_CHECKING:
    from brdfcodec.codec.encoding import LatentChoice, ProjectBase
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import SharedBasis

__all__ = [
    "BrdfDecoder",
    "BrdfEncoder",
    "ClampWarning",
    "DecodedMaterial",
    "MaskedEntries",
    "MaterialInput",
    "MaterialLibrary",
    "compress",
    "decode",
    "decompress",
    "encode",
    "encode_records",
    "measure",
    "prepare_source",
    "resolve_model",
]

MaskedEntries = Literal["unmeasured", "zero", "keep"]
ModelSpec = str | os.PathLike[str] | ModelManifest | None


def resolve_model(model: ModelSpec) -> ModelManifest:
    """A model's manifest from a folder, a decoder SHA-256, or ``None`` for the shipped default.

    Raises
    ------
    DecoderNotFoundError
        A hash that no known model has (the message lists the available ones).
    """
    if isinstance(model, ModelManifest):
        return model
    if model is None:
        return load_manifest(default_model_folder())
    text = os.fspath(model)
    if len(text) == 64 and all(c in "0123456789abcdef" for c in text.lower()) and not Path(text).exists():
        return find_model(text)
    return load_manifest(text)


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


@dataclass(frozen=True)
class _ProjectionPlan:
    """Precomputed terms of a projected base's dot products ``aⱼ = (y − m) · vⱼ``, j < P (format 1.6).

    On the basis' entries the clamped decode is y = u + δ, and the unclamped output is
    u = m + W⋆h + b + z·C (the last transposed convolution W of the hidden activations h, its bias b, and
    the linear path: the mean m and the components C). So aⱼ = (Wᵀvⱼ)·h + b·vⱼ + z·(C vⱼ) + δ·vⱼ, where Wᵀ,
    the adjoint of the transposed convolution, is a convolution with the same weights. ``adjoint`` holds
    Wᵀvⱼ for every vector of the basis (K × 32·45·45, a sixth of the vectors' size; a record that projects
    on P vectors uses the first P rows), ``bias`` b·vⱼ, ``linear`` C vⱼ; δ is 0 except where the clamp acted.
    """

    adjoint: np.ndarray  # (K, C·45·45) float32, one row per basis vector
    bias: np.ndarray  # (K,)
    linear: np.ndarray  # (latent_dim, K)
    basis: SharedBasis
    centre: np.ndarray  # (E,)

    @classmethod
    def build(cls, network: torch.nn.Module, basis: SharedBasis, centre: np.ndarray) -> _ProjectionPlan:
        count = basis.count
        last = network.upsample[-1]
        weight = last.weight.detach().float().cpu()
        grid_size = int(np.prod(NETWORK_INPUT_SHAPE))
        adjoint = []
        with torch.no_grad():
            for start in range(0, count, 8):  # 8 vectors on the grid at a time: 16 MB each
                grid = torch.zeros(min(8, count - start), grid_size)
                grid[:, torch.from_numpy(np.array(basis.entries))] = torch.from_numpy(np.array(
                    basis.vectors_uncached(start, min(8, count - start))))
                pulled = torch.nn.functional.conv2d(grid.view(-1, *NETWORK_INPUT_SHAPE), weight,
                                                    stride=last.stride, padding=last.padding)
                adjoint.append(pulled.flatten(1).numpy())
        channel_bias = last.bias.detach().float().cpu().numpy()
        plane = NETWORK_INPUT_SHAPE[1] * NETWORK_INPUT_SHAPE[2]
        bias = basis.dots(channel_bias[basis.entries // plane], count)
        index = network.valid_index.cpu().numpy()
        position = np.searchsorted(index, basis.entries)
        components = network.basis_components.float().cpu().numpy()[:, position]
        return cls(np.concatenate(adjoint), bias.astype(np.float32), basis.dots(components, count).astype(np.float32),
                   basis, np.asarray(centre, dtype=np.float32))

    def reconstruct(self, weights: np.ndarray) -> np.ndarray:
        """``centre + Σⱼ weightsⱼ vⱼ`` over the entries, on the calling thread: right after the network, torch's
        worker threads still spin on the other cores, and a second thread here ran slower than one."""
        out = self.basis.weighted_sum(weights)
        out += self.centre
        return out

    def dot_products(self, count: int, hidden: np.ndarray, z: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """aⱼ, j < ``count``, for one material: ``hidden`` flat (C·45·45,), ``z`` (latent_dim,), ``moved`` = δ
        on the entries."""
        a = self.adjoint[:count] @ hidden + self.bias[:count] + np.asarray(z, dtype=np.float32) @ self.linear[:, :count]
        where = np.flatnonzero(moved)
        if where.size:
            a += self.basis.vector_values(count, where) @ moved[where]
        return a


def _projected_vectors(record: Record) -> int:
    """P of a record whose base decode is projected on the shared basis (format 1.6), else 0."""
    layer = getattr(record, "basis", None)
    return 0 if layer is None else int(layer.project)


def _has_latent(record: Record) -> bool:
    """False for a basis-only record (format 2.1, ``layers.mu = "none"``), whose base is the linear-path mean."""
    return bool(getattr(record, "has_latent", True))


def _apply_mask(table: np.ndarray, bins: Sequence[int] | None, masked: MaskedEntries) -> np.ndarray:
    if masked == "keep":
        return table
    if masked not in ("unmeasured", "zero"):
        raise ValueError(f"masked must be 'unmeasured', 'zero' or 'keep', got {masked!r}")
    invalid = _invalid_bins() if bins is None else _invalid_bins()[..., list(bins)]
    fill = UNMEASURED_VALUE if masked == "unmeasured" else 0.0
    np.copyto(table, np.float32(fill), where=np.broadcast_to(invalid, table.shape))
    return table


class _EvalMode:
    """Puts a module in evaluation mode for a ``with`` block and restores its mode after."""

    def __init__(self, module: torch.nn.Module) -> None:
        self.module = module

    def __enter__(self) -> None:
        self.was_training = self.module.training
        self.module.eval()

    def __exit__(self, *exc: object) -> None:
        self.module.train(self.was_training)


class BrdfDecoder:
    """A loaded decoder: latent codes to mapped slices and tables.

    Parameters
    ----------
    model : str, os.PathLike, ModelManifest or None
        Model folder, decoder SHA-256 (looked up in the registry), or None for
        the shipped default model.
    device : str or torch.device, default "cpu"
    dtype : torch.dtype, default torch.float32
        Computation dtype (``torch.float16`` or ``torch.bfloat16`` where the
        device supports them). Outputs are float32 either way.

    Examples
    --------
    >>> import brdfcodec as bc
    >>> decoder = bc.BrdfDecoder()                     # the shipped default model
    >>> record = bc.LatentRecord("centre", [0.0] * decoder.latent_dim, [1.0] * decoder.latent_dim)
    >>> decoder.decode(record, phi_d_bins=[0]).shape   # stored MERL units, one φd bin
    (3, 90, 90, 1)
    """

    manifest: ModelManifest | None
    reference: DecoderReference | None

    def __init__(
        self, model: ModelSpec = None, *, device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32
    ) -> None:
        manifest = resolve_model(model)
        _, network, loaded = load_model(manifest.folder, parts=("decoder",), device=str(device))
        if network is None:  # load_model returns the parts asked for
            raise RuntimeError(f"{manifest.folder}: the decoder did not load")
        self._setup(network.to(dtype), device, dtype, loaded)

    def _setup(
        self, network: torch.nn.Module, device: str | torch.device, dtype: torch.dtype, manifest: ModelManifest | None
    ) -> None:
        self.network = network
        self.device = torch.device(device)
        self.dtype = dtype
        self.manifest = manifest
        self.reference = None if manifest is None else DecoderReference(manifest.decoder_sha256, manifest.name)
        self._latent_dim = int(network.config.latent_dim)

    @classmethod
    def from_network(
        cls, network: torch.nn.Module, *, device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32
    ) -> BrdfDecoder:
        """Wrap a decoder network held in memory (training, export): no manifest, no file reference.

        The network is not copied or converted (its parameters keep their dtypes); it is put in evaluation
        mode while it runs and given back in the mode it had. ``dtype`` is the dtype of the codes fed to it.
        """
        decoder = cls.__new__(cls)
        decoder._setup(network, device, dtype, None)
        return decoder

    @classmethod
    def for_header(
        cls, header: BvaeHeader, *, device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32
    ) -> BrdfDecoder:
        """The decoder a file refers to, found by its SHA-256 in the registry."""
        return cls(find_model(header.decoder.sha256), device=device, dtype=dtype)

    @property
    def latent_dim(self) -> int:
        """Length of the latent code."""
        return self._latent_dim

    @functools.cached_property
    def colour_dims(self) -> tuple[int, ...]:
        """Latent dimensions that control colour: from the manifest, else measured now by traversal."""
        stored = self.manifest.parameters.get("colour_dims") if self.manifest is not None else None
        if stored:
            return tuple(int(d) for d in stored)
        from brdfcodec.models.parameters import colour_dims_of, measure_dimension_effects

        return colour_dims_of(measure_dimension_effects(self))

    def check(self, header: BvaeHeader, path: str | os.PathLike[str] = "") -> None:
        """Refuse to decode a file made for another decoder.

        Raises
        ------
        DecoderMismatchError
            Names both hashes and says how to get the right model.
        LatentDimensionError
            The file's ``latent_dim`` is not the decoder's.
        BasisMismatchError, BasisError
            A record's basis layer names a shared basis this model does not have, or vectors beyond it
            (``spec/bvae-format.md`` §4.5): refused on opening, before any record is decoded.
        """
        mine = self.reference
        if mine is None or header.decoder.sha256 != mine.sha256:
            where = f"{os.fspath(path)}: " if path else ""
            own = "a decoder held in memory" if mine is None else f"{mine.sha256} ({mine.name})"
            raise DecoderMismatchError(
                f"{where}the file needs decoder {header.decoder.sha256} ({header.decoder.name}), but this decoder is "
                f"{own}; open it with BrdfDecoder.for_header, or register the model folder that made it"
            )
        if header.latent_dim != self.latent_dim:
            raise LatentDimensionError(
                path or "<bvae>",
                f"declares latent_dim {header.latent_dim}, but its decoder {header.decoder.name} "
                f"({header.decoder.sha256[:12]}…) has {self.latent_dim}: the file is inconsistent",
            )
        from brdfcodec.layers.basis import check_basis_layers

        own = self.manifest.basis_sha256 if self.manifest is not None else None
        where = os.fspath(path) or "<bvae>"
        check_basis_layers(header.entries, self.basis_named, where, own)
        for entry in header.entries:  # records without a latent start from the linear-path mean (format 2.1)
            layers = entry.layers or {}
            if layers.get("mu") == "none":
                basis = self.basis_named(str(layers["basis"]["sha256"]))
                assert basis is not None  # checked just above
                self._centre_for(entry.name, basis, where)

    def _codes(self, codes: npt.ArrayLike) -> tuple[np.ndarray, bool]:
        array = np.asarray(codes, dtype=np.float32)
        single = array.ndim == 1
        batch = np.array(array.reshape(-1, array.shape[-1]) if array.ndim else array.reshape(1, 1))
        if batch.shape[-1] != self.latent_dim:
            raise ValueError(f"codes must have {self.latent_dim} values each, got shape {array.shape}")
        if not np.isfinite(batch).all():
            raise ValueError("latent codes must be finite")
        return batch, single

    def _run(self, batch: np.ndarray, channels: tuple[int, ...] | None, batch_size: int) -> np.ndarray:
        """The batched network loop: clamped mapped output (:func:`~brdfcodec.representation.clamp_mapped`)."""
        if batch_size < 1:
            raise ValueError(f"batch_size must be at least 1, got {batch_size}")
        outputs = []
        with codec_threads(), torch.inference_mode(), _EvalMode(self.network):
            for start in range(0, len(batch), batch_size):
                z = torch.from_numpy(batch[start : start + batch_size]).to(self.device, self.dtype)
                out = self.network(z) if channels is None else self.network.forward_channels(z, channels)
                outputs.append(out.float().cpu().numpy())
        out = np.concatenate(outputs) if len(outputs) > 1 else outputs[0]
        return clamp_mapped(out, out=out)

    def decode_mapped(self, codes: npt.ArrayLike, *, batch_size: int = 16) -> npt.NDArray[np.float32]:
        """Mapped slices of latent codes.

        Parameters
        ----------
        codes : array_like, shape (B, latent_dim) or (latent_dim,)
            Latent codes (any finite values; the output is clamped).
        batch_size : int, default 16
            Codes run through the network at once.

        Returns
        -------
        ndarray of float32, shape (B, 63, 90, 90) or (63, 90, 90)
            Mapped values in [0, MAPPED_MAX], network layout.
        """
        batch, single = self._codes(codes)
        out = self._run(batch, None, batch_size)
        return out[0] if single else out

    def decode_channels(self, code: npt.ArrayLike, channels: Sequence[int]) -> npt.NDArray[np.float32]:
        """Only some mapped channels of one latent code, shape (len(channels), 90, 90)."""
        batch, _ = self._codes(np.asarray(code, dtype=np.float32).reshape(-1))
        return self._run(batch, tuple(channels), 1)[0]

    def mapped_for_bins(self, record: Record, phi_d_bins: Sequence[int]) -> npt.NDArray[np.float32]:
        """Mapped slices (63, 90, 90) with only the kept slices that ``phi_d_bins`` need filled (others 0)."""
        slots = kept_slots_for_bins(phi_d_bins)
        if len(slots) > N_KEPT_SLICES // 2 or _projected_vectors(record):  # a projection needs every entry
            return self.mapped_record(record)
        out = np.zeros(NETWORK_INPUT_SHAPE, dtype=np.float32)
        if not _has_latent(record):  # no network at all: the mean's channels, then the layers' for those slots
            channels = network_channels_for_slots(slots)
            out[channels] = self._with_layers(record, self._mean_base(record)[channels], slots)
        elif isinstance(record, GraftRecord):
            own = network_channels_for_slots(slots, colours=(0, 2))
            out[own] = self.decode_channels(record.mu, own)
            green = network_channels_for_slots(slots, colours=(1,))
            out[green] = self.decode_channels(record.second_code(), network_channels_for_slots(slots, colours=(0,)))
        else:
            channels = network_channels_for_slots(slots)
            out[channels] = self._with_layers(record, self.decode_channels(record.mu, channels), slots)
        return out

    @functools.cached_property
    def shared_basis(self) -> SharedBasis | None:
        """The model's shared basis (``basis.safetensors``, checked against ``model.json``), or None."""
        if self.manifest is None or not self.manifest.basis_sha256:
            return None
        from brdfcodec.layers.basis import BASIS_FILE, load_shared_basis

        return load_shared_basis(self.manifest.folder / BASIS_FILE, self.manifest.basis_sha256)

    def basis_named(self, sha256: str) -> SharedBasis | None:
        """The model's shared basis (:attr:`shared_basis`) if it has this SHA-256, else None: a model ships one
        basis, and a file's basis layers decode with the model whose basis they name (``spec/bvae-format.md``
        §4.5)."""
        basis = self.shared_basis
        return basis if basis is not None and basis.sha256 == sha256 else None

    @property
    def projection_centre(self) -> npt.NDArray[np.float32]:
        """The centre of a projected base (``spec/bvae-format.md`` §4.5) over the current shared basis' entries:
        the decoder's linear-path mean (``basis_mean``, float16 widened) there, shape (E,).

        Raises
        ------
        BasisError
            The model has no shared basis, its decoder no linear path, or the linear path does not cover
            every entry of the basis.
        """
        from brdfcodec.layers.basis import BasisError

        basis = self.shared_basis
        if basis is None:
            raise BasisError("a projected base needs the model's shared basis; this model has none")
        return self._centre_on(basis)

    def _centre_on(self, basis: SharedBasis) -> npt.NDArray[np.float32]:
        from brdfcodec.layers.basis import BasisError

        cache = self.__dict__.setdefault("_centres", {})
        if basis.sha256 not in cache:
            mean, index = getattr(self.network, "basis_mean", None), getattr(self.network, "valid_index", None)
            if mean is None or index is None:
                raise BasisError("a projected base is centred on the decoder's linear-path mean, and a record without "
                                 "a latent starts from it; this decoder has no linear path")
            index_np = index.cpu().numpy()
            position = np.minimum(np.searchsorted(index_np, basis.entries), len(index_np) - 1)
            if not np.array_equal(index_np[position], basis.entries):
                raise BasisError("the decoder's linear path does not cover every entry of the shared basis")
            cache[basis.sha256] = mean.float().cpu().numpy()[position]
        return cache[basis.sha256]

    def _centre_for(self, name: str, basis: SharedBasis, where: str = "") -> npt.NDArray[np.float32]:
        """:meth:`_centre_on` for a record without a latent; its :class:`BasisError` names the file and the
        record."""
        from brdfcodec.layers.basis import BasisError

        try:
            return self._centre_on(basis)
        except BasisError as error:
            place = f"{where}: " if where else ""
            raise BasisError(f"{place}record {name!r} has no latent (format 2.1) and decodes from the decoder's "
                             f"linear-path mean: {error}") from None

    def _mean_base(self, record: Record) -> npt.NDArray[np.float32]:
        """The base of a record without a latent (``spec/bvae-format.md`` §4.6): the decoder's linear-path mean m
        at the shared basis' entries and 0 elsewhere, shape (63, 90, 90), a new array. No network runs."""
        layer = record.basis  # type: ignore[union-attr]  # a record without a latent has a basis layer
        basis = self._basis_of(record, layer.sha256)
        return basis.on_grid(self._centre_for(record.name, basis))

    def _projection_plan(self, basis: SharedBasis) -> _ProjectionPlan:
        """What a fast projected decode needs for every vector of ``basis``, computed once per decoder and basis
        (records that project on fewer vectors use its first rows)."""
        cache = self.__dict__.setdefault("_projection_plans", {})
        if basis.sha256 not in cache:
            cache[basis.sha256] = _ProjectionPlan.build(self.network, basis, self._centre_on(basis))
        return cache[basis.sha256]

    def _projected_mapped(self, record: LayeredRecord) -> npt.NDArray[np.float32]:
        """The mapped slices of a record whose basis layer projects its base (format 1.6), all 63 channels.

        The same sum as :meth:`project_base` followed by the layers (``spec/bvae-format.md`` §4.5), taken
        the fast way: the projection's dot products ``(y − m) · v_j`` go through the network's last layer,
        ``G h`` with ``G`` its adjoint applied to the vectors (:class:`_ProjectionPlan`), plus the linear
        path's ``z · (C vⱼ)``, the last layer's bias, and the entries the clamp moved; then one pass over the
        vectors adds the projection and the basis layer together; then the detail layer, if any.
        """
        layer = record.basis
        assert layer is not None
        basis = self._basis_of(record, layer.sha256)
        if layer.project > basis.count:
            from brdfcodec.layers.basis import BasisError

            raise BasisError(f"{record.name}: the record projects its base on {layer.project} basis vectors, but "
                             f"this model's shared basis holds {basis.count}")
        count, c, first = layer.project, layer.coefficients(), layer.first
        if first + len(c) > basis.count:
            basis.check_vectors(first, len(c))  # refused with the sizes (BasisError)
        plan = self._projection_plan(basis)
        from brdfcodec.layers.detail import decode_detail

        batch, _ = self._codes(record.mu)
        with torch.inference_mode(), _EvalMode(self.network):
            z = torch.from_numpy(batch).to(self.device, self.dtype)
            hidden, unbounded = self.network.hidden_and_unbounded(z)
            h = hidden.float().cpu().numpy().reshape(-1)
            u = unbounded.float().cpu().numpy()[0]
        mapped = clamp_mapped(u)  # a new array: u is still needed
        on_basis = basis.entry_mask  # boolean: gathers and scatters faster than the index array
        unclamped = u.reshape(-1)[on_basis]
        moved = mapped.reshape(-1)[on_basis] - unclamped  # the clamp's change (0 almost everywhere)
        if not np.isfinite(moved).all():  # a non-finite network output: the direct sum
            self.project_base(record, mapped)
            mapped.reshape(-1)[on_basis] += basis.weighted_sum(c, first)
        else:
            weights = np.zeros(max(count, first + len(c)), dtype=np.float32)
            weights[:count] = plan.dot_products(count, h, batch[0], moved)
            weights[first : first + len(c)] += c
            mapped.reshape(-1)[on_basis] = plan.reconstruct(weights)
        if record.detail is not None:
            mapped += decode_detail(record.detail).reshape(mapped.shape)
        return clamp_mapped(mapped, out=mapped)

    def project_base(self, record: Record, mapped: np.ndarray) -> None:
        """Replace, in place, a clamped base decode ``mapped`` (63, 90, 90) by its projection when the record's
        basis layer asks for one (``layers.basis.project``, format 1.6); nothing otherwise."""
        count = _projected_vectors(record)
        if not count:
            return
        basis = self._basis_of(record, record.basis.sha256)  # type: ignore[union-attr]
        if count > basis.count:
            from brdfcodec.layers.basis import BasisError

            raise BasisError(f"{record.name}: the record projects its base on {count} basis vectors, but this "
                             f"model's shared basis holds {basis.count}")
        flat = mapped.reshape(-1)
        flat[basis.entries] = basis.project(flat[basis.entries], self._centre_on(basis), count)

    def _basis_of(self, record: Record, sha256: str) -> SharedBasis:
        """The shared basis a record's basis layer names; :class:`BasisMismatchError` naming both hashes when
        this decoder's model has no basis by that hash (projected records included)."""
        basis = self.basis_named(sha256)
        if basis is None:
            own = self.manifest.basis_sha256 if self.manifest is not None else None
            raise BasisMismatchError(
                f"{record.name}: the record's basis layer needs shared basis {sha256}, but this "
                f"decoder's model has {own or 'none'}; decode it with the model that wrote it"
            )
        return basis

    def _layer_residuals(self, record: Record, slots: Sequence[int] | None = None) -> list[np.ndarray]:
        """A record's layers decoded to mapped residuals, in the order they are added (basis, then detail).

        Empty for a base-only record. A full decode gets one ``(63, 90, 90)`` residual, both layers summed
        (:func:`~brdfcodec.layers.layer_sum.layered_residual`). A partial decode gets each layer's channels of
        the kept ``slots`` only, in :func:`~brdfcodec.representation.network_channels_for_slots` order.
        """
        basis_layer, detail = getattr(record, "basis", None), getattr(record, "detail", None)
        if basis_layer is None and detail is None:
            return []
        basis = None if basis_layer is None else self._basis_of(record, basis_layer.sha256)
        if slots is None:
            from brdfcodec.layers.layer_sum import layered_residual

            residual = layered_residual(basis, basis_layer, detail)
            return [] if residual is None else [residual]
        residuals = []
        if basis_layer is not None and basis is not None:
            channels = network_channels_for_slots(slots)
            residuals.append(basis.residual_channels(basis_layer.coefficients(), channels, basis_layer.first))
        if detail is not None:
            from brdfcodec.layers.detail import decode_detail

            residuals.append(decode_detail(detail, slots).reshape(-1, *NETWORK_INPUT_SHAPE[1:]))
        return residuals

    def _with_layers(self, record: Record, mapped: np.ndarray, slots: Sequence[int] | None = None) -> np.ndarray:
        """A layered record's decode: base + basis layer + detail layer, then the one clamp (spec §4.4, §6).

        ``mapped`` is the clamped base decode of all 63 channels, or (partial decoding) of the channels of
        the kept ``slots`` only. The layers are decoded after the network, on the calling thread: beside the
        network, on a thread of their own, they made a decode slower on 2 cores, not faster
        (``benchmarks/README.md``).
        """
        residuals = self._layer_residuals(record, slots)
        if not residuals:
            return mapped
        for residual in residuals:
            mapped += residual
        return clamp_mapped(mapped, out=mapped)

    def mapped_record(self, record: Record) -> npt.NDArray[np.float32]:
        """Mapped slices of a record; a graft record's green block is the second code's red block; a record
        without a latent (format 2.1) is the linear-path mean plus its layers, clamped."""
        with codec_threads():
            if not _has_latent(record):
                return self._with_layers(record, self._mean_base(record))
            if isinstance(record, GraftRecord):
                # One code at a time, so M1 is bit-identical to decoding V1 as a plain record.
                out = self.decode_mapped(record.mu)
                out[GREEN_BLOCK] = self.decode_mapped(record.second_code())[RED_BLOCK]
                return out
            if _projected_vectors(record):
                return self._projected_mapped(record)  # type: ignore[arg-type]
            return self._with_layers(record, self.decode_mapped(record.mu))

    def decode(
        self,
        record: Record,
        *,
        phi_d_bins: Sequence[int] | None = None,
        masked: MaskedEntries = "unmeasured",
    ) -> npt.NDArray[np.float32]:
        """Decoded table of a record in stored MERL units.

        Parameters
        ----------
        record : LatentRecord or GraftRecord
        phi_d_bins : sequence of int, optional
            Only these φd bins (each in [0, 180)); all by default.
        masked : {"unmeasured", "zero", "keep"}, default "unmeasured"
            Below-horizon bins: ``-1`` (MERL's unmeasured marker), ``0``, or
            the network's value.

        Returns
        -------
        ndarray of float32, shape (3, 90, 90, K)
        """
        self._check_record(record)
        with codec_threads():
            if phi_d_bins is None:
                return _apply_mask(table_from_mapped(self.mapped_record(record)), None, masked)
            bins = validate_phi_d_bins(phi_d_bins)
            table = table_from_mapped(self.mapped_for_bins(record, bins), phi_d_bins=bins)
            return _apply_mask(table, bins, masked)

    #: Former name of :meth:`decode`.
    table = decode

    def decode_many(
        self, records: Sequence[Record], *, masked: MaskedEntries = "unmeasured", batch_size: int = 16
    ) -> Iterator[npt.NDArray[np.float32]]:
        """Full tables of many records, decoded ``batch_size`` at a time (a generator: one table built at a time)."""
        for record in records:
            self._check_record(record)
        for start in range(0, len(records), batch_size):
            chunk = records[start : start + batch_size]
            # Projected records decode on their own (their network pass also yields the projection's terms), and
            # records without a latent run no network (format 2.1).
            latent = [r for r in chunk if isinstance(r, LatentRecord) and not _projected_vectors(r)
                      and _has_latent(r)]
            batch: Iterator[np.ndarray] = iter(())
            if latent:
                batch = iter(self.decode_mapped(np.stack([record.mu for record in latent]), batch_size=batch_size))
            for record in chunk:  # grafts need two codes each: decoded on their own
                with codec_threads():
                    if isinstance(record, LatentRecord) and not _projected_vectors(record) and _has_latent(record):
                        mapped = self._with_layers(record, next(batch))
                    else:
                        mapped = self.mapped_record(record)
                    table = _apply_mask(table_from_mapped(mapped), None, masked)
                yield table

    def _check_record(self, record: Record) -> None:
        if record.latent_dim != self.latent_dim:
            raise ValueError(f"{record.name}: latent dimension {record.latent_dim}, decoder needs {self.latent_dim}")


@dataclass(frozen=True)
class MaterialInput:
    """A material already turned into a network input (a dataset row), with its table when known.

    Attributes
    ----------
    name : str
    inputs : ndarray of float32, shape (63, 90, 90)
        :func:`~brdfcodec.representation.network_input_from_table` of the table.
    source : MerlBRDF or None
        The table, for measuring the error and the source hash; None if not at hand.
    mask : ndarray of bool, shape (63, 90, 90), or None
        Valid input entries (refinement and rate control measure over them);
        by default the source's, or every entry above the horizon.
    """

    name: str
    inputs: np.ndarray
    source: MerlBRDF | None = None
    mask: np.ndarray | None = None

    def input_mask(self) -> np.ndarray:
        """Valid entries of :attr:`inputs`, shape (63, 90, 90)."""
        if self.mask is not None:
            return self.mask
        if self.source is not None:
            return network_input_from_table(self.source.values, self.source.mask)[1]
        above = to_network_layout(np.broadcast_to(kept_slice_horizon_mask(), (3, *kept_slice_horizon_mask().shape)))
        return np.broadcast_to(above, self.inputs.shape)


class BrdfEncoder:
    """A loaded encoder: MERL tables to latent records.

    Parameters
    ----------
    model : str, os.PathLike, ModelManifest or None
        As for :class:`BrdfDecoder`.
    device : str or torch.device, default "cpu"
    effort : int, default 1
        Latent refinement at encode time, 0 to 3 (0: the encoder's μ; see
        :mod:`brdfcodec.codec.refine`). Each level costs encode time
        (``benchmarks/effort_study.py``; docs: Layers and rate control).
    bytes : int, optional
        Rate control: the largest record payload per material (base + detail layer).
    max_relae : float, optional
        Rate control: the smallest record whose decoded table has at most this RelAE.
    metric : {"mapped", "linear"}, default "mapped"
        RelAE used by ``max_relae``.
    detail_step : float, optional
        A fixed detail-layer quantisation step (mapped units) instead of a target.
    latent_dtype : {"float32", "float16"}, default "float32"
        How the file will store latents (counts toward ``bytes``).
    basis : bool, default True
        Whether rate control may add a basis layer (coefficients on the model's shared basis,
        ``spec/bvae-format.md`` §4.5) when the model has one.
    project_base : {"auto", "always", "never"} or bool, default "auto"
        Whether records with a basis layer project their base decode on the shared basis (format 1.6,
        ``layers.basis.project``, :data:`~brdfcodec.codec.encoding.PROJECTED_BASE_VECTORS` vectors): lower
        error at equal size on most materials, a slower decode (``reports/rd-study/projection-cost.json``).
        ``"auto"`` fits both and keeps
        the better per material; ``True``/``False`` mean ``"always"``/``"never"``. Ignored where the model's
        decoder has no linear path to centre the projection on.
    latent : {"auto", "always"}, default "auto"
        With ``bytes`` or ``max_relae``: ``"auto"`` lets rate control pick a record without a latent (format 2.1,
        the decoder's linear-path mean plus basis coefficients) where its error is lower; it decodes like any
        other but cannot be edited. ``"always"``: every record keeps a latent code that edits can move.
    """

    manifest: ModelManifest | None

    def __init__(
        self,
        model: ModelSpec = None,
        *,
        device: str | torch.device = "cpu",
        effort: int = 1,
        bytes: int | None = None,  # noqa: A002 - the CLI's --bytes
        max_relae: float | None = None,
        metric: Literal["mapped", "linear"] = "mapped",
        detail_step: float | None = None,
        latent_dtype: LatentDtype = "float32",
        basis: bool = True,
        project_base: ProjectBase | bool = "auto",
        latent: LatentChoice = "auto",
    ) -> None:
        from brdfcodec.codec.encoding import EncodeOptions

        self.options = EncodeOptions(
            effort=effort, bytes_budget=bytes, max_relae=max_relae, metric=metric, detail_step=detail_step,
            latent_itemsize=2 if latent_dtype == "float16" else 4, basis=basis, project_base=project_base,
            latent=latent,
        )
        manifest = resolve_model(model)
        network, _, loaded = load_model(manifest.folder, parts=("encoder",), device=str(device))
        if network is None:  # load_model returns the parts asked for
            raise RuntimeError(f"{manifest.folder}: the encoder did not load")
        self._setup(network, device, loaded)

    def _setup(self, network: torch.nn.Module, device: str | torch.device, manifest: ModelManifest | None) -> None:
        self.network = network
        self.device = torch.device(device)
        self.manifest = manifest
        self.reference = None if manifest is None else DecoderReference(manifest.decoder_sha256, manifest.name)

    @classmethod
    def from_network(cls, network: torch.nn.Module, *, device: str | torch.device = "cpu") -> BrdfEncoder:
        """Wrap an encoder network held in memory (training, export): no manifest.

        The network is put in evaluation mode while it runs and given back in the mode it had.
        """
        from brdfcodec.codec.encoding import EncodeOptions

        encoder = cls.__new__(cls)
        encoder.options = EncodeOptions(effort=0)  # the network's own posterior: what training measures
        encoder._setup(network, device, None)
        return encoder

    @functools.cached_property
    def decoder(self) -> BrdfDecoder:
        """The model's decoder (loaded on first use: refinement and layers need it)."""
        if self.manifest is None:
            raise ValueError("an encoder wrapped with from_network has no model folder to load a decoder from")
        return BrdfDecoder(self.manifest, device=self.device)

    def encode_arrays(
        self,
        names: Sequence[str],
        inputs: np.ndarray,
        masks: np.ndarray,
        sources: Sequence[MerlBRDF | None],
        *,
        source_digests: Sequence[str] | None = None,
    ) -> list[LatentRecord]:
        """Records of materials given as network inputs ``(B, 63, 90, 90)`` and masks, with effort and rate control.

        ``sources`` (tables) are needed for ``max_relae``; otherwise they only add their SHA-256 to ``meta``
        (``source_digests``, when given, are their :func:`~brdfcodec.io.merl.source_digest`, already taken).
        """
        mu, sigma = self.posterior_from_inputs(inputs, batch_size=max(len(inputs), 1))
        records = self.make_records(names, mu, sigma, sources, source_digests)
        if self.options.effort == 0 and not self.options.layered:
            return records
        from brdfcodec.codec.encoding import layer_records

        with codec_threads():  # refinement and rate control: thousands of small torch operations
            return layer_records(records, self.decoder, inputs, masks, sources, self.options)

    def posterior_from_inputs(
        self, inputs: npt.ArrayLike, *, batch_size: int = 8, log_variance: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """Posterior of network inputs: the batched encoder loop.

        Parameters
        ----------
        inputs : array_like, shape (B, 63, 90, 90)
            Mapped inputs, invalid entries 0
            (:func:`~brdfcodec.representation.network_input_from_table`).
        batch_size : int, default 8
        log_variance : bool, default False
            Return log σ² (as the network gives it) instead of σ.

        Returns
        -------
        mu, sigma (or log σ²) : ndarray of float32, shape (B, latent_dim)
            σ = exp(½·clamp(log σ², −60, 60)), finite and > 0.
        """
        batch = np.asarray(inputs, dtype=np.float32)
        if batch.ndim != 4 or batch.shape[1:] != NETWORK_INPUT_SHAPE:
            expected = ", ".join(map(str, NETWORK_INPUT_SHAPE))
            raise ValueError(f"inputs must have shape (B, {expected}), got {batch.shape}")
        if batch_size < 1:
            raise ValueError(f"batch_size must be at least 1, got {batch_size}")
        mus, spreads = [], []
        with codec_threads(), torch.inference_mode(), _EvalMode(self.network):
            for start in range(0, len(batch), batch_size):
                x = torch.from_numpy(np.ascontiguousarray(batch[start : start + batch_size])).to(self.device)
                mu, logvar = self.network(x)
                logvar = logvar.float()
                mus.append(mu.float().cpu().numpy())
                spread = logvar if log_variance else torch.exp(0.5 * logvar.clamp(-60.0, 60.0))
                spreads.append(spread.cpu().numpy())
        if not mus:
            empty = np.empty((0, int(self.network.config.latent_dim)), dtype=np.float32)
            return empty, empty.copy()
        return np.concatenate(mus), np.concatenate(spreads)

    def posterior(self, brdfs: Sequence[MerlBRDF], *, batch_size: int = 8) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and standard deviation, each of shape (len(brdfs), latent_dim), float32."""
        mus, sigmas = [], []
        for start in range(0, len(brdfs), batch_size):
            chunk = [prepare_source(b) for b in brdfs[start : start + batch_size]]
            inputs = np.stack([network_input_from_table(b.values, b.mask)[0] for b in chunk])
            mu, sigma = self.posterior_from_inputs(inputs, batch_size=batch_size)
            mus.append(mu)
            sigmas.append(sigma)
        return np.concatenate(mus), np.concatenate(sigmas)

    def encode(self, brdf: MerlBRDF, *, name: str | None = None) -> LatentRecord:
        """One material's record (metadata: source SHA-256 and encoder SHA-256)."""
        return self.encode_many([brdf], names=[name] if name else None)[0]

    def encode_many(
        self, brdfs: Sequence[MerlBRDF], *, names: Sequence[str] | None = None, batch_size: int = 8
    ) -> list[LatentRecord]:
        """Records of many materials, encoded in batches (with the encoder's effort and rate options)."""
        labels = list(names) if names is not None else [b.name or f"material-{i}" for i, b in enumerate(brdfs)]
        records: list[LatentRecord] = []
        # A table's SHA-256 (MERL's 35 MB: the largest single cost of an effort-0 encode) is taken on a thread of its
        # own while the table is prepared (hashlib lets go of the GIL), and waited for before the network: torch's
        # threads beside the hashing thread ran the network markedly slower.
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="bvae-sha256") as hashing:
            for start in range(0, len(brdfs), batch_size):
                group = brdfs[start : start + batch_size]
                digests = hashing.submit(lambda group=group: [source_digest(b) for b in group])
                chunk = [prepare_source(b) for b in group]
                arrays = [network_input_from_table(b.values, b.mask) for b in chunk]
                records += self.encode_arrays(
                    labels[start : start + batch_size], np.stack([a[0] for a in arrays]),
                    np.stack([a[1] for a in arrays]), list(chunk), source_digests=digests.result(),
                )
        return records

    def make_records(
        self,
        names: Sequence[str],
        mu: np.ndarray,
        sigma: np.ndarray,
        sources: Sequence[MerlBRDF | None],
        digests: Sequence[str] | None = None,
    ) -> list[LatentRecord]:
        """Records from posteriors, with metadata: the encoder's SHA-256, and the source's where it is known
        (``digests[i]`` when given, else :func:`source_digest` of ``sources[i]``)."""
        records = []
        for i, name in enumerate(names):
            meta = {} if self.manifest is None else {"encoder_sha256": self.manifest.encoder_sha256}
            source = sources[i]
            if source is not None:
                meta["source_sha256"] = digests[i] if digests is not None else source_digest(source)
                if source.source_kind is not None:
                    meta["source_kind"] = source.source_kind
            records.append(LatentRecord(name, mu[i], sigma[i], meta))
        return records


def measure(record: Record, decoder: BrdfDecoder, source: MerlBRDF) -> LatentRecord | GraftRecord:
    """The record with ``meta["relae"]`` set to the RelAE of its decode against ``source`` (and its provenance).

    ``source_sha256`` and ``source_kind`` are set from ``source``, replacing
    the record's (``source_kind`` is left out for a MERL file).

    The RelAE (mapped and linear) is measured against the source as
    :func:`prepare_source` gives it. A material that reflects nothing (all
    0) has no RelAE (0/0): ``relae`` is then left out, with a warning.
    """
    source = prepare_source(source, warn=False)
    estimate = decoder.decode(record, masked="keep").astype(np.float64)
    linear, mapped = relae_both(source.values, estimate, source.mask)
    meta = {key: value for key, value in record.meta.items() if key not in ("relae", "source_kind")}
    meta["source_sha256"] = source_digest(source)  # the provenance of what was measured against
    if source.source_kind is not None:
        meta["source_kind"] = source.source_kind
    relae = {"mapped": mapped.overall, "linear": linear.overall}
    if all(np.isfinite(v) for v in relae.values()):
        meta["relae"] = relae
    else:
        where = os.fspath(source.path) if source.path is not None else (source.name or record.name)
        warnings.warn(f"{where}: RelAE is undefined for a material that reflects nothing (black); not stored",
                      stacklevel=2)
    if isinstance(record, GraftRecord):
        return GraftRecord(record.name, record.mu, record.sigma, record.graft_dims, record.graft_values, meta)
    return replace(record, meta=meta)  # the same kind: a layered record keeps its layers


class DecodedMaterial:
    """One material of a library, decoded on first use and cached.

    Parameters
    ----------
    record : LatentRecord or GraftRecord
    decoder : BrdfDecoder
        Must be the decoder the record was made for (the library checks it).
    """

    def __init__(self, record: Record, decoder: BrdfDecoder) -> None:
        self.record = record
        self.decoder = decoder

    @property
    def name(self) -> str:
        """Material name."""
        return self.record.name

    @functools.cached_property
    def mapped(self) -> npt.NDArray[np.float32]:
        """Decoder output, (63, 90, 90) mapped slices in [0, MAPPED_MAX] (computed once)."""
        return self.decoder.mapped_record(self.record)

    def table(
        self, *, phi_d_bins: Sequence[int] | None = None, masked: MaskedEntries = "unmeasured"
    ) -> npt.NDArray[np.float32]:
        """Stored-unit table, all or chosen φd bins (see :meth:`BrdfDecoder.decode`).

        Chosen bins of a material not yet decoded are decoded alone (only the
        kept slices they need); the full decode is cached once made.
        """
        if phi_d_bins is None:
            return _apply_mask(table_from_mapped(self.mapped), None, masked)
        if "mapped" not in self.__dict__:
            return self.decoder.decode(self.record, phi_d_bins=phi_d_bins, masked=masked)
        bins = validate_phi_d_bins(phi_d_bins)
        return _apply_mask(table_from_mapped(self.mapped, phi_d_bins=bins), bins, masked)

    @functools.cached_property
    def _reflectance(self) -> npt.NDArray[np.float32]:
        table = _apply_mask(reflectance_from_mapped(self.mapped), None, "zero")  # no trip through stored units
        table.setflags(write=False)
        return table

    def reflectance(self) -> npt.NDArray[np.float32]:
        """Reflectance in 1/sr, linear RGB, shape (3, 90, 90, 180); 0 below the horizon (cached, read-only)."""
        return self._reflectance

    #: Former name of :meth:`reflectance`.
    physical = reflectance

    def eval(
        self, wi: npt.ArrayLike, wo: npt.ArrayLike, *, mode: Literal["nearest", "trilinear"] = "nearest"
    ) -> npt.NDArray[np.float64]:
        """Reflectance (1/sr, linear RGB) at direction pairs, shape (..., 3); see :func:`brdfcodec.representation.lookup.lookup`."""
        from brdfcodec.representation.lookup import lookup

        mask = np.broadcast_to(horizon_mask(), (3, *horizon_mask().shape))
        return lookup(self._reflectance, wi, wo, mode=mode, mask=mask)

    def to_merl(self, *, masked: MaskedEntries = "unmeasured") -> MerlBRDF:
        """The decoded table as a :class:`~brdfcodec.io.merl.MerlBRDF` (float64, for writing or metrics)."""
        return MerlBRDF(self.table(masked=masked).astype(np.float64), name=self.name)


class MaterialLibrary(Mapping[str, DecodedMaterial]):
    """A ``.bvae`` file (or its bytes) opened for decoding materials on demand: name → :class:`DecodedMaterial`.

    Opening reads the header only and checks that ``decoder`` (or the model
    found by the file's decoder hash) is the one the file needs. Indexing by
    name reads that record and returns a lazily decoded, cached
    :class:`DecodedMaterial`. This is the one library class: :func:`decode`
    returns it for bytes, ``MaterialLibrary(path)`` opens a file.

    Parameters
    ----------
    path : str or os.PathLike
    decoder : BrdfDecoder, optional
        Reuse a loaded decoder; it must match the file.

    Raises
    ------
    DecoderNotFoundError, DecoderMismatchError, BvaeFormatError

    Examples
    --------
    >>> import brdfcodec as bc
    >>> from brdfcodec.examples import example_library
    >>> with bc.MaterialLibrary(example_library()) as library:
    ...     print(len(library), library.names[:2], library["gold-metallic-paint"].table(phi_d_bins=[90]).shape)
    90 ['alumina-oxide', 'aluminium'] (3, 90, 90, 1)
    """

    def __init__(self, path: str | os.PathLike[str], *, decoder: BrdfDecoder | None = None) -> None:
        self.path: Path | None = Path(path)
        reader = BvaeReader(path)
        try:
            self._open(reader.header, reader.read, reader.close, decoder, path)
        except BaseException:
            reader.close()
            raise

    def _open(
        self,
        header: BvaeHeader,
        read: Callable[[str], Record],
        close: Callable[[], None],
        decoder: BrdfDecoder | None,
        where: str | os.PathLike[str],
    ) -> None:
        self.header = header
        self._read = read
        self._close = close
        try:
            self.decoder = decoder if decoder is not None else BrdfDecoder.for_header(header)
        except DecoderNotFoundError as error:  # say which file needs the missing decoder
            raise type(error)(f"{os.fspath(where)}: {error}") from None
        self.decoder.check(header, where)
        self._materials: dict[str, DecodedMaterial] = {}

    @classmethod
    def from_bytes(cls, data: bytes, *, decoder: BrdfDecoder | None = None) -> MaterialLibrary:
        """A library from the bytes of a ``.bvae`` file (parsed and checked at once, records decoded lazily)."""
        parsed = parse_bvae(bytes(data))
        records = {record.name: record for record in parsed.records}
        library = cls.__new__(cls)
        library.path = None
        library._open(parsed.header, records.__getitem__, lambda: None, decoder, "<bytes>")
        return library

    def __enter__(self) -> MaterialLibrary:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the file (decoded materials stay usable)."""
        self._close()

    @property
    def names(self) -> list[str]:
        """Material names in file order."""
        return self.header.names

    def __len__(self) -> int:
        return len(self.header.entries)

    def __iter__(self) -> Iterator[str]:
        return iter(self.header.names)

    def __contains__(self, name: object) -> bool:
        return name in self.header.names

    def __getitem__(self, name: str) -> DecodedMaterial:
        if name not in self._materials:
            self._materials[name] = DecodedMaterial(self._read(name), self.decoder)
        return self._materials[name]

    def forget(self, name: str | None = None) -> None:
        """Drop a decoded material (or all) from the cache; it is decoded again if used again."""
        if name is None:
            self._materials.clear()
        else:
            self._materials.pop(name, None)

    def record(self, name: str) -> Record:
        """The stored record of a material (no decoding)."""
        return self[name].record

    @property
    def decoded_count(self) -> int:
        """How many materials have been decoded so far."""
        return sum("mapped" in m.__dict__ for m in self._materials.values())


EncodeSource = MerlBRDF | MaterialInput | str | os.PathLike[str]


def _as_input(source: EncodeSource, index: int, name: str | None) -> MaterialInput:
    if isinstance(source, MaterialInput):
        return source if name is None else MaterialInput(name, source.inputs, source.source, source.mask)
    brdf = prepare_source(source if isinstance(source, MerlBRDF) else read_measured(source))
    label = name or brdf.name or f"material-{index}"
    inputs, mask = network_input_from_table(brdf.values, brdf.mask)
    return MaterialInput(label, inputs, brdf, mask)


def encode_records(
    sources: Iterable[EncodeSource],
    *,
    names: Sequence[str] | None = None,
    encoder: BrdfEncoder | None = None,
    decoder: BrdfDecoder | None = None,
    measure_error: bool = True,
    batch_size: int = 8,
    on_batch: Callable[[list[Record]], None] | None = None,
) -> list[Record]:
    """Encode materials into records, ``batch_size`` at a time (sources are read as they are needed).

    Parameters
    ----------
    sources : iterable of MerlBRDF, MaterialInput or MERL file path
        Consumed lazily, so a generator that loads one table at a time keeps
        at most ``batch_size`` tables in memory.
    names : sequence of str, optional
        Record names; by default each source's name (file stem, ``MerlBRDF.name``).
    encoder : BrdfEncoder, optional
        The shipped default model's encoder when absent.
    decoder : BrdfDecoder, optional
        For measuring; loaded from the encoder's model when needed.
    measure_error : bool, default True
        Decode each record and store its RelAE against its source table in
        ``meta["relae"]`` (skipped for a :class:`MaterialInput` without table).
    batch_size : int, default 8
    on_batch : callable, optional
        Called with the records of each batch as it is done (progress).

    Returns
    -------
    list of LatentRecord
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be at least 1, got {batch_size}")
    encoder = encoder if encoder is not None else BrdfEncoder()
    if measure_error and decoder is None:
        decoder = encoder.decoder
    labels = iter(names) if names is not None else itertools.repeat(None)
    records: list[Record] = []
    numbered = enumerate(sources)
    while chunk := list(itertools.islice(numbered, batch_size)):
        items = [_as_input(source, index, next(labels)) for index, source in chunk]
        sources_of = [item.source for item in items]
        batch: list[Record] = list(encoder.encode_arrays(
            [item.name for item in items],
            np.stack([item.inputs for item in items]),
            np.stack([item.input_mask() for item in items]),
            sources_of,
        ))
        if measure_error and decoder is not None:
            batch = [r if s is None else measure(r, decoder, s) for r, s in zip(batch, sources_of, strict=True)]
        records += batch
        if on_batch is not None:
            on_batch(batch)
    return records


def encode(
    sources: EncodeSource | Iterable[EncodeSource],
    *,
    names: Sequence[str] | None = None,
    model: ModelSpec = None,
    latent_dtype: LatentDtype = "float32",
    measure_error: bool = True,
    batch_size: int = 8,
    effort: int = 1,
    bytes: int | None = None,  # noqa: A002 - the CLI's --bytes
    max_relae: float | None = None,
    metric: Literal["mapped", "linear"] = "mapped",
    provenance: bool = False,
    latent: LatentChoice = "auto",
) -> bytes:
    """Encode MERL tables into the bytes of one ``.bvae`` file (one material, or a library of many).

    The inverse of :func:`decode`: ``decode(encode([brdf]))[brdf.name]`` is the
    material as the model reconstructs it.

    Parameters
    ----------
    sources : MerlBRDF, MaterialInput, MERL file path, or an iterable of them
    names : sequence of str, optional
        Material names (by default the sources' names).
    model : model folder, decoder SHA-256, or None for the default
    latent_dtype : {"float32", "float16"}
    measure_error : bool, default True
        Measure each record's RelAE against its source (``meta["relae"]``; stored with ``provenance``).
    batch_size : int, default 8
    effort, bytes, max_relae, metric
        Encode-time refinement and rate control, as for :class:`BrdfEncoder`.
    provenance : bool, default False
        Store each record's provenance in the file (``spec/bvae-format.md`` §5: source SHA-256 and kind,
        RelAE, encoder, effort, rate control). By default the file holds names and records only.
    latent : {"auto", "always"}, default "auto"
        Whether rate control may write records without a latent, as for :class:`BrdfEncoder`.

    Returns
    -------
    bytes
        A complete ``.bvae`` file (``spec/bvae-format.md``).

    Examples
    --------
    >>> import brdfcodec as bc
    >>> from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
    >>> data = bc.encode([ANALYTIC_PRESETS["gold"].to_merl()], measure_error=False)
    >>> data[1:5], len(data)   # one material: a header naming the decoder, then 64 bytes of latents
    (b'BVAE', 136)
    >>> bc.decode(data)["gold"].table(phi_d_bins=[0]).shape
    (3, 90, 90, 1)
    """
    items = [sources] if isinstance(sources, MerlBRDF | MaterialInput | str | os.PathLike) else sources
    encoder = BrdfEncoder(
        model, effort=effort, bytes=bytes, max_relae=max_relae, metric=metric, latent_dtype=latent_dtype,
        latent=latent,
    )
    records = encode_records(items, names=names, encoder=encoder, measure_error=measure_error, batch_size=batch_size)
    if encoder.reference is None:  # loaded from a model folder, so it has one
        raise RuntimeError("the encoder has no decoder reference")
    if not provenance:
        records = without_provenance(records)
    return encode_bvae(records, encoder.reference, latent_dtype=latent_dtype)


def decode(data: bytes, *, decoder: BrdfDecoder | None = None) -> MaterialLibrary:
    """The materials of a ``.bvae`` file's bytes: the inverse of :func:`encode`.

    Parameters
    ----------
    data : bytes
        A complete ``.bvae`` file.
    decoder : BrdfDecoder, optional
        Reuse a loaded decoder; by default the one the file names is found by its SHA-256.

    Returns
    -------
    MaterialLibrary
        Name → :class:`DecodedMaterial`; each decoded when first used.

    Raises
    ------
    BvaeFormatError, DecoderNotFoundError, DecoderMismatchError
    """
    return MaterialLibrary.from_bytes(data, decoder=decoder)


def compress(
    sources: EncodeSource | Iterable[EncodeSource],
    output: str | os.PathLike[str],
    *,
    names: Sequence[str] | None = None,
    model: ModelSpec = None,
    latent_dtype: LatentDtype = "float32",
    measure_error: bool = True,
    overwrite: bool = False,
    effort: int = 1,
    bytes: int | None = None,  # noqa: A002 - the CLI's --bytes
    max_relae: float | None = None,
    metric: Literal["mapped", "linear"] = "mapped",
    provenance: bool = False,
    latent: LatentChoice = "auto",
) -> int:
    """Write :func:`encode` of the sources to a ``.bvae`` file, atomically (options as for :func:`encode`).

    Returns
    -------
    int
        Bytes written.
    """
    check_output_path(output, overwrite=overwrite)  # before the work, not after
    data = encode(
        sources, names=names, model=model, latent_dtype=latent_dtype, measure_error=measure_error,
        effort=effort, bytes=bytes, max_relae=max_relae, metric=metric, provenance=provenance, latent=latent,
    )
    with atomic_output(output, overwrite=overwrite) as tmp:
        Path(tmp).write_bytes(data)
    return len(data)


def decompress(
    path: str | os.PathLike[str],
    material: str | None = None,
    *,
    phi_d_bins: Sequence[int] | None = None,
    masked: MaskedEntries = "unmeasured",
) -> npt.NDArray[np.float32]:
    """Decode one material of a ``.bvae`` file (the only one, or the one named).

    Returns
    -------
    ndarray of float32, shape (3, 90, 90, K)
        Stored MERL units; see :meth:`BrdfDecoder.decode`.
    """
    with MaterialLibrary(path) as library:
        if material is None:
            if len(library) != 1:
                raise ValueError(
                    f"{path}: holds {len(library)} materials; name one ({', '.join(library.names[:10])}"
                    f"{', …' if len(library) > 10 else ''})"
                )
            material = library.names[0]
        return library[material].table(phi_d_bins=phi_d_bins, masked=masked)
