"""The decoder: latent codes and layered records to tables (spec/bvae-format.md §6).

Part of :mod:`brdfcodec.codec`, which re-exports the public names.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.conventions import LATENT_LIMIT, N_KEPT_SLICES, NETWORK_INPUT_SHAPE
from brdfcodec.errors import (
    BasisMismatchError,
    DecoderMismatchError,
    LatentDimensionError,
)
from brdfcodec.format.bvae import (
    BvaeHeader,
    DecoderReference,
    GraftRecord,
    LatentRecord,
    Record,
)
from brdfcodec.models.registry import find_model
from brdfcodec.models.store import ModelManifest, load_model
from brdfcodec.representation import (
    GREEN_BLOCK,
    RED_BLOCK,
    clamp_mapped,
    kept_slots_for_bins,
    network_channels_for_slots,
    table_from_mapped,
    validate_phi_d_bins,
)
from brdfcodec.representation.energy import energy_bound_scale_mapped, scale_mapped
from brdfcodec.representation.highlight_guard import guard_highlight
from brdfcodec.runtime.threads import codec_threads

if TYPE_CHECKING:
    from brdfcodec.format.layered_record import LayeredRecord
    from brdfcodec.layers.basis import SharedBasis

from brdfcodec.codec.device_decode import _EvalMode, network_batches, table_from_mapped_host
from brdfcodec.codec.devices import indexed_device
from brdfcodec.codec.prepare import MaskedEntries, ModelSpec, _apply_mask, resolve_model
from brdfcodec.codec.projection import _has_latent, _projected_vectors, _ProjectionPlan

__all__ = ["CPU_NETWORK_BATCH", "BrdfDecoder"]

#: The most codes the decoder network takes at once on the CPU (:meth:`BrdfDecoder.network_batch`).
CPU_NETWORK_BATCH = 2


def is_edited(record: Record) -> bool:
    """Whether a record is an edit (its metadata holds ``edit``, ``spec/bvae-format.md`` §5): its decode is bounded."""
    return "edit" in record.meta


def _guarded(record: Record, mapped: np.ndarray) -> np.ndarray:
    """An edited record's clamped mapped slices after the highlight guard (``spec/bvae-format.md`` §6 step 6;
    :mod:`brdfcodec.representation.highlight_guard`); any other record's as they are, the same array."""
    return guard_highlight(mapped) if is_edited(record) else mapped


def _table(
    mapped: np.ndarray, bins: Sequence[int] | None, energy_bound: bool, masked: MaskedEntries,
    compiled: bool = False,
) -> npt.NDArray[np.float32]:
    """The table of full mapped slices (only ``bins`` when given), times the energy bound's factor when asked,
    below-horizon bins as ``masked`` says.

    The order of ``spec/bvae-format.md`` §6: the slices are interpolated to the bins and unmapped (step 2),
    then multiplied by the factor (step 5), which is computed from the whole table. A full table takes the
    host decode (:func:`~brdfcodec.codec.device_decode.table_from_mapped_host`: the same steps, its
    exponentials vectorised, the mask applied block by block; ``compiled``: its passes compiled, for batches).
    """
    scale = energy_bound_scale_mapped(mapped) if energy_bound else 1.0
    if bins is None:
        return table_from_mapped_host(mapped, scale=scale, masked=masked, compiled=compiled)
    return _apply_mask(table_from_mapped(mapped, phi_d_bins=bins, scale=scale), bins, masked)


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
        self.device = indexed_device(device)  # cuda → cuda:N, as its tensors' .device
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

    def network_batch(self, batch_size: int) -> int:
        """Codes the network takes at once when asked for ``batch_size``: at most :data:`CPU_NETWORK_BATCH` on
        the CPU, ``batch_size`` on other devices.

        On the CPU a network call's working buffers grow with the batch; above glibc's largest mmap threshold
        (32 MB) they are returned to the system when the call ends and faulted in again by the next one, which
        cost more than a batch saves (measured by ``benchmarks/test_bench_decode_path.py``, group
        ``decode-network-batch``). Every batched decode runs its codes
        through the network in the same batches (:func:`~brdfcodec.codec.device_decode.network_batches`), so that
        all see the same network output.
        """
        if batch_size < 1:
            raise ValueError(f"batch_size must be at least 1, got {batch_size}")
        return min(batch_size, CPU_NETWORK_BATCH) if self.device.type == "cpu" else batch_size

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
        if mine is None or not header.decoder.matches(mine.sha256):
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
        """The batched network loop (:func:`~brdfcodec.codec.device_decode.network_batches`): clamped mapped
        output (:func:`~brdfcodec.representation.clamp_mapped`)."""
        outputs = []
        with codec_threads(), torch.inference_mode(), _EvalMode(self.network):
            for part in network_batches(self, len(batch), batch_size):
                z = torch.from_numpy(batch[part]).to(self.device, self.dtype)
                out = self.network(z) if channels is None else self.network.forward_channels(z, channels)
                outputs.append(out.float().cpu().numpy())
        out = np.concatenate(outputs) if len(outputs) > 1 else outputs[0]
        return clamp_mapped(out, out=out)

    def _mapped_lazily(self, codes: np.ndarray, batch_size: int) -> Iterator[np.ndarray]:
        """:meth:`decode_mapped` of ``codes`` one code at a time, run through the network a network batch at a
        time as they are asked for (:meth:`network_batch`): no array of every code's slices is built."""
        batch, _ = self._codes(codes)
        for part in network_batches(self, len(batch), batch_size):
            yield from self._run(batch[part], None, part.stop - part.start)

    def decode_mapped(self, codes: npt.ArrayLike, *, batch_size: int = 16) -> npt.NDArray[np.float32]:
        """Mapped slices of latent codes.

        Parameters
        ----------
        codes : array_like, shape (B, latent_dim) or (latent_dim,)
            Latent codes (any finite values; the output is clamped).
        batch_size : int, default 16
            Codes run through the network at once on a GPU; on the CPU at most :data:`CPU_NETWORK_BATCH`
            (:meth:`network_batch`).

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
            return self._mapped_record(record)
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
        return _guarded(record, out)  # the guard acts on each kept slot's columns alone (§6 step 6)

    @functools.cached_property
    def shared_basis(self) -> SharedBasis | None:
        """The model's shared basis (``basis.safetensors``, checked against ``model.json``), or None."""
        if self.manifest is None or not self.manifest.basis_sha256:
            return None
        from brdfcodec.layers.basis import BASIS_FILE, load_shared_basis

        return load_shared_basis(self.manifest.folder / BASIS_FILE, self.manifest.basis_sha256)

    def basis_named(self, sha256: str) -> SharedBasis | None:
        """The model's shared basis (:attr:`shared_basis`) if it has this SHA-256, its leading vectors where
        ``model.json`` names an earlier basis of that SHA-256 they are (``basis_prefixes``, ``spec/model.md``
        §5), else None: a file's basis layers decode with the model whose basis they name
        (``spec/bvae-format.md`` §4.5). ``sha256`` may be a short reference (its first 16 hex digits, format 2.6);
        the basis returned is named by its full SHA-256."""
        basis = self.shared_basis
        if basis is None:
            return None
        from brdfcodec.layers.basis_storage import basis_reference_target

        earlier = self.manifest.basis_prefixes if self.manifest is not None else {}
        named = basis_reference_target(sha256, basis.sha256, earlier)
        if named is None:
            return None
        return basis if named == basis.sha256 else basis.leading(earlier[named], named)

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
        (records that project on fewer vectors use its first rows). An earlier basis that the model's basis
        extends (``basis_prefixes``) is its leading vectors: it uses the model's basis' plan, so a file naming
        it costs no second one."""
        own = self.shared_basis
        if own is not None and self.manifest is not None and basis.sha256 in self.manifest.basis_prefixes:
            basis = own
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
            code = np.clip(batch[0], -LATENT_LIMIT, LATENT_LIMIT)  # the network's input (§6 step 2)
            weights[:count] = plan.dot_products(count, h, code, moved)
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
            short = " (a short reference: none of the model's bases, or two, start with it)" if len(sha256) < 64 else ""
            raise BasisMismatchError(
                f"{record.name}: the record's basis layer needs shared basis {sha256}{short}, but this "
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

    def mapped_record(self, record: Record, *, energy_bound: bool | None = None) -> npt.NDArray[np.float32]:
        """Mapped slices of a record (network layout, shape (63, 90, 90)).

        A graft record's green block is the second code's red block; a record without a latent (format 2.1)
        is the linear-path mean plus its layers, clamped.

        Parameters
        ----------
        record : Record
        energy_bound : bool, optional
            Apply the energy bound (:meth:`energy_scale`, ``spec/bvae-format.md`` §6 step 5) in the mapped
            domain. By default, exactly for edited records (:func:`is_edited`).

        Notes
        -----
        With the bound, the slices are exactly the kept φd bins of the bounded table, but the bound is a
        factor on reflectance, which does not commute with the interpolation in the mapped domain: the
        table of bounded slices (:func:`~brdfcodec.representation.table_from_mapped`) is not the bounded
        table at the other bins. For tables, use :meth:`decode`, or the slices with ``energy_bound=False``
        and ``table_from_mapped(..., scale=decoder.energy_scale(record))``.
        """
        mapped = self._mapped_record(record)
        if energy_bound if energy_bound is not None else is_edited(record):
            mapped = scale_mapped(mapped, energy_bound_scale_mapped(mapped)).astype(np.float32, copy=False)
        return mapped

    def energy_scale(self, record: Record) -> float:
        """The energy bound's factor for a record: ``min(1, 1 / max a)`` over its decode's directional albedo.

        See :mod:`brdfcodec.representation.energy`; 1 when the decode conserves energy.
        """
        return energy_bound_scale_mapped(self._mapped_record(record))

    def _mapped_record(self, record: Record) -> npt.NDArray[np.float32]:
        """Clamped mapped slices of a record, layers added; an edit's after the highlight guard (§6 step 6)."""
        return _guarded(record, self._unguarded_mapped(record))

    def _unguarded_mapped(self, record: Record) -> npt.NDArray[np.float32]:
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
        energy_bound: bool | None = None,
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
        energy_bound : bool, optional
            Multiply the table by ``min(1, 1 / max a)``, a its directional albedo
            (``spec/bvae-format.md`` §6 step 5), applied after the interpolation, so that it reflects at
            most the light it receives. By default, exactly for edited records (:func:`is_edited`): an
            encoded material decodes as measured, an edit never creates energy.

        Returns
        -------
        ndarray of float32, shape (3, 90, 90, K)
        """
        self._check_record(record)
        bound = energy_bound if energy_bound is not None else is_edited(record)
        with codec_threads():
            bins = None if phi_d_bins is None else validate_phi_d_bins(phi_d_bins)
            if bound or bins is None:  # the bound's factor needs the whole table
                return _table(self._mapped_record(record), bins, bound, masked)
            return _apply_mask(table_from_mapped(self.mapped_for_bins(record, bins), phi_d_bins=bins), bins, masked)

    def decode_many(
        self, records: Sequence[Record], *, masked: MaskedEntries = "unmeasured", batch_size: int = 16
    ) -> Iterator[npt.NDArray[np.float32]]:
        """Full tables of many records, decoded ``batch_size`` at a time (a generator: one table built at a time).

        The work after the network runs compiled (Numba, :mod:`brdfcodec.representation.stepped_kernel`), bit for
        bit :meth:`decode`'s from the same network output (the network itself may round otherwise in batches of
        another size: :meth:`network_batch`): the first batch decode of a process imports Numba and loads the
        kernels (a one-time cost in time and memory); ``BRDFCODEC_NO_JIT=1`` keeps the NumPy path.
        """
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
                batch = self._mapped_lazily(np.stack([record.mu for record in latent]), batch_size)
            for record in chunk:  # grafts need two codes each: decoded on their own
                with codec_threads():
                    if isinstance(record, LatentRecord) and not _projected_vectors(record) and _has_latent(record):
                        mapped = _guarded(record, self._with_layers(record, next(batch)))
                    else:
                        mapped = self._mapped_record(record)
                    table = _table(mapped, None, is_edited(record), masked, compiled=True)
                yield table

    def decode_many_tensor(
        self,
        records: Sequence[Record] | torch.Tensor | npt.ArrayLike,
        *,
        masked: MaskedEntries = "unmeasured",
        energy_bound: bool | None = None,
        batch_size: int = 16,
        out: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Full tables of many records (or latent codes) as one torch tensor on the decoder's device.

        The tables of :meth:`decode_many`, stacked, with the work after the network (clamp, layers, slice
        interpolation, unmapping, energy bound, mask) done as tensor operations where the network runs
        (:mod:`brdfcodec.codec.device_decode`): on a GPU nothing passes through the host. Hand the result
        to Dr.Jit/Mitsuba, JAX or CuPy without a copy through DLPack (``torch.utils.dlpack.to_dlpack(tables)``
        or ``tables.__dlpack__()``). On the CPU ``tables.numpy()`` is what :meth:`decode_many` yields, up to
        float32 rounding; a GPU unmaps in float32 from float64 arguments, within 1e-6 mapped of it
        (``spec/bvae-format.md`` §9).

        Parameters
        ----------
        records : sequence of Record, or array_like / torch.Tensor of shape (N, latent_dim)
            Records (any kind: grafts, projected bases and records without a latent take their mapped slices
            from the NumPy path, then continue on the device; layers are decoded on the host and added on the
            device), or finite latent codes of plain materials (a tensor already on the device is not copied).
        masked : {"unmeasured", "zero", "keep"}, default "unmeasured"
            Below-horizon bins: ``-1`` (MERL's unmeasured marker), ``0``, or the decoded value.
        energy_bound : bool, optional
            The energy bound (``spec/bvae-format.md`` §6 step 5) for every table (True) or none (False); by
            default, exactly for edited records (:func:`is_edited`), never for bare codes.
        batch_size : int, default 16
            Codes run through the network at once on a GPU; on the CPU at most :data:`CPU_NETWORK_BATCH`
            (:meth:`network_batch`).
        out : torch.Tensor of float32, shape (N, 3, 90, 90, 180), optional
            A contiguous tensor on :attr:`device` to write the tables into, for a renderer that decodes batch
            after batch into the same memory (a new 17.5 MB a table is otherwise allocated and first touched on
            every call); a new tensor by default.

        Returns
        -------
        torch.Tensor of float32, shape (N, 3, 90, 90, 180)
            Stored MERL units, on :attr:`device` (17.5 MB a table: ask for as many as the device holds); ``out``
            itself when given.

        Raises
        ------
        ValueError
            Codes of the wrong width or not finite, a bad ``masked`` or ``batch_size``, a record of another
            latent size, or an ``out`` of another shape, dtype or device, or not contiguous.
        TypeError
            ``out`` is not a tensor.
        """
        from brdfcodec.codec.device_decode import decode_many_tensor

        return decode_many_tensor(self, records, masked=masked, energy_bound=energy_bound, batch_size=batch_size,
                                  out=out)

    def evaluate_tensor(
        self,
        records: Sequence[Record] | torch.Tensor | npt.ArrayLike,
        wi: torch.Tensor | npt.ArrayLike,
        wo: torch.Tensor | npt.ArrayLike,
        *,
        energy_bound: bool | None = None,
        batch_size: int = 16,
    ) -> torch.Tensor:
        """Values of many records (or latent codes) at direction pairs, on the decoder's device, without tables.

        Each pair's MERL bin (the nearest-bin lookup of ``spec/conventions.md`` §3, as
        :func:`~brdfcodec.representation.lookup.lookup`) is made from the network's kept φd slices alone
        (:mod:`brdfcodec.codec.device_lookup`): the same value as that bin of :meth:`decode_many`'s table with
        ``masked="zero"``, up to float32 rounding, for a renderer that needs values at some directions and not
        17.5 MB a material.

        Parameters
        ----------
        records : sequence of Record, or array_like / torch.Tensor of shape (B, latent_dim)
            As for :meth:`decode_many_tensor` (any record kind; finite latent codes of plain materials).
        wi, wo : array_like or torch.Tensor, shape (N, 3) or (B, N, 3)
            Incoming and outgoing directions in the shading frame (z = normal), any finite non-zero length,
            broadcast together: one set for every material, or one per material.
        energy_bound : bool, optional
            As for :meth:`decode_many_tensor`: by default exactly for edited records, never for bare codes.
        batch_size : int, default 16
            Codes run through the network at once on a GPU; on the CPU at most :data:`CPU_NETWORK_BATCH`
            (:meth:`network_batch`).

        Returns
        -------
        torch.Tensor of float32, shape (B, N, 3)
            RGB in stored MERL units (times ``brdfcodec.conventions.MERL_COLOR_SCALE`` for reflectance in 1/sr),
            on :attr:`device`; 0 where either direction is at or below the horizon or the bin is below it.

        Raises
        ------
        ValueError
            Codes of the wrong width or not finite, directions that are not 3-vectors, not finite, zero, or of a
            shape that is neither (N, 3) nor (B, N, 3), a bad ``batch_size``, a record of another latent size.
        """
        from brdfcodec.codec.device_lookup import evaluate_tensor

        return evaluate_tensor(self, records, wi, wo, energy_bound=energy_bound, batch_size=batch_size)

    def _check_record(self, record: Record) -> None:
        if record.latent_dim != self.latent_dim:
            raise ValueError(f"{record.name}: latent dimension {record.latent_dim}, decoder needs {self.latent_dim}")


