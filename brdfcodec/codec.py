"""Encoding MERL tables to latent records and decoding records back to tables.

:class:`BrdfEncoder` and :class:`BrdfDecoder` hold a loaded model and its
device and are meant to be reused; :func:`compress` and :func:`decompress`
are one-shot shortcuts. :class:`MaterialLibrary` opens a ``.bvae`` file and
decodes a material only when it is first used, so a scene that uses 3
materials of a library of 100 decodes 3.

Decoded tables follow ``spec/bvae-format.md`` §6: stored MERL units
(multiply by the channel scale for reflectance), float32, and entries whose
bin lies below the horizon set to ``-1`` (unmeasured) unless asked otherwise.
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.bvae_format import (
    BvaeHeader,
    BvaeReader,
    DecoderReference,
    GraftRecord,
    LatentDtype,
    LatentRecord,
    Record,
    write_bvae,
)
from brdfcodec.conventions import MAPPED_MAX, MERL_COLOR_SCALE, N_KEPT_SLICES, NETWORK_INPUT_SHAPE, UNMEASURED_VALUE
from brdfcodec.dataset import material_arrays
from brdfcodec.errors import (
    DecoderMismatchError,
    DecoderNotFoundError,
    LatentDimensionError,
    UnmeasuredMaterialError,
)
from brdfcodec.mask import horizon_mask
from brdfcodec.merl import MerlBRDF, read_merl
from brdfcodec.metrics import error_report
from brdfcodec.models.registry import default_model_folder, find_model
from brdfcodec.models.store import ModelManifest, load_manifest, load_model
from brdfcodec.transforms import kept_slots_for_bins, table_from_network_output, unmap_values

__all__ = [
    "BrdfDecoder",
    "BrdfEncoder",
    "DecodedMaterial",
    "MaskedEntries",
    "MaterialLibrary",
    "compress",
    "decompress",
    "prepare_source",
    "resolve_model",
]

MaskedEntries = Literal["unmeasured", "zero", "keep"]
ModelSpec = str | os.PathLike[str] | ModelManifest | None

#: Green block of the network layout (channel k holds colour k // 21).
_GREEN = slice(N_KEPT_SLICES, 2 * N_KEPT_SLICES)
_RED = slice(0, N_KEPT_SLICES)


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
    return MerlBRDF(clamped, name=brdf.name, path=brdf.path, _file_sha256=brdf.sha256)


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
    """

    def __init__(
        self, model: ModelSpec = None, *, device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32
    ) -> None:
        manifest = resolve_model(model)
        _, network, self.manifest = load_model(manifest.folder, parts=("decoder",), device=str(device))
        assert network is not None
        self.network = network.to(dtype)
        self.device = torch.device(device)
        self.dtype = dtype
        self.reference = DecoderReference(self.manifest.decoder_sha256, self.manifest.name)

    @classmethod
    def for_header(
        cls, header: BvaeHeader, *, device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32
    ) -> BrdfDecoder:
        """The decoder a file refers to, found by its SHA-256 in the registry."""
        return cls(find_model(header.decoder.sha256), device=device, dtype=dtype)

    @property
    def latent_dim(self) -> int:
        """Length of the latent code."""
        return self.manifest.config.latent_dim

    @functools.cached_property
    def colour_dims(self) -> tuple[int, ...]:
        """Latent dimensions that control colour: from the manifest, else measured now by traversal."""
        stored = self.manifest.parameters.get("colour_dims")
        if stored:
            return tuple(int(d) for d in stored)
        from brdfcodec.parameters import colour_dims_of, measure_dimension_effects

        return colour_dims_of(measure_dimension_effects(self))

    def check(self, header: BvaeHeader, path: str | os.PathLike[str] = "") -> None:
        """Refuse to decode a file made for another decoder.

        Raises
        ------
        DecoderMismatchError
            Names both hashes and says how to get the right model.
        LatentDimensionError
            The file's ``latent_dim`` is not the decoder's.
        """
        if header.decoder.sha256 != self.reference.sha256:
            where = f"{os.fspath(path)}: " if path else ""
            raise DecoderMismatchError(
                f"{where}the file needs decoder {header.decoder.sha256} ({header.decoder.name}), but this decoder is "
                f"{self.reference.sha256} ({self.reference.name}); open it with BrdfDecoder.for_header, or register "
                "the model folder that made it"
            )
        if header.latent_dim != self.latent_dim:
            raise LatentDimensionError(
                path or "<bvae>",
                f"declares latent_dim {header.latent_dim}, but its decoder {header.decoder.name} "
                f"({header.decoder.sha256[:12]}…) has {self.latent_dim}: the file is inconsistent",
            )

    def decode_mapped(self, codes: npt.ArrayLike, *, batch_size: int = 16) -> npt.NDArray[np.float32]:
        """Mapped slices of latent codes.

        Parameters
        ----------
        codes : array_like, shape (B, latent_dim) or (latent_dim,)
            Latent codes (any finite values; the output is clamped).

        Returns
        -------
        ndarray of float32, shape (B, 63, 90, 90) or (63, 90, 90)
            Mapped values in [0, MAPPED_MAX], network layout.
        """
        array = np.asarray(codes, dtype=np.float32)
        single = array.ndim == 1
        batch = np.array(array.reshape(-1, array.shape[-1]) if array.ndim else array.reshape(1, 1))
        if batch.shape[-1] != self.latent_dim:
            raise ValueError(f"codes must have {self.latent_dim} values each, got shape {array.shape}")
        if not np.isfinite(batch).all():
            raise ValueError("latent codes must be finite")
        outputs = []
        with torch.inference_mode():
            for start in range(0, len(batch), batch_size):
                z = torch.from_numpy(batch[start : start + batch_size]).to(self.device, self.dtype)
                outputs.append(self.network(z).float().nan_to_num_(0.0).clamp_(0.0).cpu().numpy())
        out = np.concatenate(outputs) if len(outputs) > 1 else outputs[0]
        return out[0] if single else out

    def decode_channels(self, code: npt.ArrayLike, channels: Sequence[int]) -> npt.NDArray[np.float32]:
        """Only some mapped channels of one latent code, shape (len(channels), 90, 90)."""
        z = np.array(code, dtype=np.float32).reshape(1, -1)
        if z.shape[1] != self.latent_dim or not np.isfinite(z).all():
            raise ValueError(f"a code must hold {self.latent_dim} finite values, got {code}")
        with torch.inference_mode():
            out = self.network.forward_channels(torch.from_numpy(z).to(self.device, self.dtype), tuple(channels))
            return out[0].float().nan_to_num_(0.0).clamp_(0.0).cpu().numpy()

    def mapped_for_bins(self, record: Record, phi_d_bins: Sequence[int]) -> npt.NDArray[np.float32]:
        """Mapped slices (63, 90, 90) with only the kept slices that ``phi_d_bins`` need filled (others 0)."""
        slots = kept_slots_for_bins(phi_d_bins)
        if len(slots) > N_KEPT_SLICES // 2:
            return self.mapped_record(record)
        out = np.zeros(NETWORK_INPUT_SHAPE, dtype=np.float32)
        if isinstance(record, GraftRecord):
            own = [c * N_KEPT_SLICES + s for c in (0, 2) for s in slots]
            out[own] = self.decode_channels(record.mu, own)
            out[[N_KEPT_SLICES + s for s in slots]] = self.decode_channels(record.second_code(), list(slots))
        else:
            channels = [c * N_KEPT_SLICES + s for c in range(3) for s in slots]
            out[channels] = self.decode_channels(record.mu, channels)
        return out

    def mapped_record(self, record: Record) -> npt.NDArray[np.float32]:
        """Mapped slices of a record; a graft record's green block is the second code's red block."""
        if isinstance(record, GraftRecord):
            # One code at a time, so M1 is bit-identical to decoding V1 as a plain record.
            out = self.decode_mapped(record.mu)
            out[_GREEN] = self.decode_mapped(record.second_code())[_RED]
            return out
        return self.decode_mapped(record.mu)

    def table(
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
        mapped = self.mapped_record(record) if phi_d_bins is None else self.mapped_for_bins(record, phi_d_bins)
        table = table_from_network_output(mapped, phi_d_bins=phi_d_bins)
        return _apply_mask(table, phi_d_bins, masked)

    def tables(
        self, records: Sequence[Record], *, masked: MaskedEntries = "unmeasured", batch_size: int = 16
    ) -> Iterator[npt.NDArray[np.float32]]:
        """Full tables of many records, decoded ``batch_size`` at a time (a generator: one table built at a time)."""
        for record in records:
            self._check_record(record)
        for start in range(0, len(records), batch_size):
            chunk = records[start : start + batch_size]
            codes = [r.mu for r in chunk if isinstance(r, LatentRecord)]
            batch = iter(self.decode_mapped(np.stack(codes)) if codes else ())
            for record in chunk:  # grafts need two codes each: decoded on their own
                mapped = next(batch) if isinstance(record, LatentRecord) else self.mapped_record(record)
                yield _apply_mask(table_from_network_output(mapped), None, masked)

    def _check_record(self, record: Record) -> None:
        if record.latent_dim != self.latent_dim:
            raise ValueError(f"{record.name}: latent dimension {record.latent_dim}, decoder needs {self.latent_dim}")


class BrdfEncoder:
    """A loaded encoder: MERL tables to latent records.

    Parameters
    ----------
    model : str, os.PathLike, ModelManifest or None
        As for :class:`BrdfDecoder`.
    device : str or torch.device, default "cpu"
    """

    def __init__(self, model: ModelSpec = None, *, device: str | torch.device = "cpu") -> None:
        manifest = resolve_model(model)
        network, _, self.manifest = load_model(manifest.folder, parts=("encoder",), device=str(device))
        assert network is not None
        self.network = network
        self.device = torch.device(device)
        self.reference = DecoderReference(self.manifest.decoder_sha256, self.manifest.name)

    def posterior_from_inputs(self, inputs: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Posterior of network inputs ``(B, 63, 90, 90)`` (mapped, masked entries 0): mean and std, float32."""
        batch = np.array(inputs, dtype=np.float32)
        if batch.ndim != 4 or batch.shape[1:] != NETWORK_INPUT_SHAPE:
            expected = ", ".join(map(str, NETWORK_INPUT_SHAPE))
            raise ValueError(f"inputs must have shape (B, {expected}), got {batch.shape}")
        with torch.inference_mode():
            mu, logvar = self.network(torch.from_numpy(batch).to(self.device))
            sigma = torch.exp(0.5 * logvar.float().clamp(-60.0, 60.0))
            return mu.float().cpu().numpy(), sigma.cpu().numpy()

    def posterior(self, brdfs: Sequence[MerlBRDF], *, batch_size: int = 8) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and standard deviation, each of shape (len(brdfs), latent_dim), float32."""
        mus, sigmas = [], []
        for start in range(0, len(brdfs), batch_size):
            mu, sigma = self.posterior_from_inputs(
                np.stack([material_arrays(prepare_source(b))[0] for b in brdfs[start : start + batch_size]])
            )
            mus.append(mu)
            sigmas.append(sigma)
        return np.concatenate(mus), np.concatenate(sigmas)

    def encode(self, brdf: MerlBRDF, *, name: str | None = None) -> LatentRecord:
        """One material's record (metadata: source SHA-256 and encoder SHA-256)."""
        return self.encode_many([brdf], names=[name] if name else None)[0]

    def encode_many(
        self, brdfs: Sequence[MerlBRDF], *, names: Sequence[str] | None = None, batch_size: int = 8
    ) -> list[LatentRecord]:
        """Records of many materials, encoded in batches."""
        mu, sigma = self.posterior(brdfs, batch_size=batch_size)
        labels = list(names) if names is not None else [b.name or f"material-{i}" for i, b in enumerate(brdfs)]
        return self.make_records(labels, mu, sigma, brdfs)

    def make_records(
        self, names: Sequence[str], mu: np.ndarray, sigma: np.ndarray, sources: Sequence[MerlBRDF | None]
    ) -> list[LatentRecord]:
        """Records from posteriors, with metadata: the encoder's SHA-256, and the source's where it is known."""
        records = []
        for i, name in enumerate(names):
            meta = {"encoder_sha256": self.manifest.encoder_sha256}
            if sources[i] is not None:
                meta["source_sha256"] = sources[i].sha256  # type: ignore[union-attr]
            records.append(LatentRecord(name, mu[i], sigma[i], meta))
        return records


def measure(record: Record, decoder: BrdfDecoder, source: MerlBRDF) -> LatentRecord | GraftRecord:
    """The record with ``meta["relae"]`` set to the RelAE of its decode against ``source`` (and its SHA-256).

    The RelAE (mapped and linear) is measured against the source as
    :func:`prepare_source` gives it. A material that reflects nothing (all
    0) has no RelAE (0/0): ``relae`` is then left out, with a warning.
    """
    source = prepare_source(source, warn=False)
    estimate = decoder.table(record, masked="keep").astype(np.float64)
    report = error_report(source.values, estimate, source.mask)
    meta = {key: value for key, value in record.meta.items() if key != "relae"}
    meta["source_sha256"] = source.sha256
    relae = {"mapped": report.relae_mapped.overall, "linear": report.relae_linear.overall}
    if all(np.isfinite(v) for v in relae.values()):
        meta["relae"] = relae
    else:
        where = os.fspath(source.path) if source.path is not None else (source.name or record.name)
        warnings.warn(f"{where}: RelAE is undefined for a material that reflects nothing (black); not stored",
                      stacklevel=2)
    if isinstance(record, GraftRecord):
        return GraftRecord(record.name, record.mu, record.sigma, record.graft_dims, record.graft_values, meta)
    return LatentRecord(record.name, record.mu, record.sigma, meta)


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
        """Decoder output, (63, 90, 90) mapped slices (computed once)."""
        return self.decoder.mapped_record(self.record)

    def table(
        self, *, phi_d_bins: Sequence[int] | None = None, masked: MaskedEntries = "unmeasured"
    ) -> npt.NDArray[np.float32]:
        """Stored-unit table, all or chosen φd bins (see :meth:`BrdfDecoder.table`).

        Chosen bins of a material not yet decoded are decoded alone (only the
        kept slices they need); the full decode is cached once made.
        """
        if phi_d_bins is not None and "mapped" not in self.__dict__:
            return self.decoder.table(self.record, phi_d_bins=phi_d_bins, masked=masked)
        return _apply_mask(table_from_network_output(self.mapped, phi_d_bins=phi_d_bins), phi_d_bins, masked)

    @functools.cached_property
    def _physical(self) -> npt.NDArray[np.float32]:
        table = self.table(masked="zero")
        table *= MERL_COLOR_SCALE.astype(np.float32).reshape(3, 1, 1, 1)
        return table

    def physical(self) -> npt.NDArray[np.float32]:
        """Reflectance in 1/sr, linear RGB, shape (3, 90, 90, 180); 0 below the horizon (cached, read-only)."""
        view = self._physical.view()
        view.setflags(write=False)
        return view

    def eval(
        self, wi: npt.ArrayLike, wo: npt.ArrayLike, *, mode: Literal["nearest", "trilinear"] = "nearest"
    ) -> npt.NDArray[np.float64]:
        """Reflectance (1/sr, linear RGB) at direction pairs, shape (..., 3); see :func:`brdfcodec.lookup.lookup`."""
        from brdfcodec.lookup import lookup

        mask = np.broadcast_to(horizon_mask(), (3, *horizon_mask().shape))
        return lookup(self._physical, wi, wo, mode=mode, mask=mask)

    def to_merl(self, *, masked: MaskedEntries = "unmeasured") -> MerlBRDF:
        """The decoded table as a :class:`~brdfcodec.merl.MerlBRDF` (float64, for writing or metrics)."""
        return MerlBRDF(self.table(masked=masked).astype(np.float64), name=self.name)


class MaterialLibrary:
    """A ``.bvae`` file opened for decoding materials on demand.

    Opening reads the header only and checks that ``decoder`` (or the model
    found by the file's decoder hash) is the one the file needs. Indexing by
    name reads that record and returns a lazily decoded, cached
    :class:`DecodedMaterial`.

    Parameters
    ----------
    path : str or os.PathLike
    decoder : BrdfDecoder, optional
        Reuse a loaded decoder; it must match the file.

    Raises
    ------
    DecoderNotFoundError, DecoderMismatchError, BvaeFormatError
    """

    def __init__(self, path: str | os.PathLike[str], *, decoder: BrdfDecoder | None = None) -> None:
        self.path = Path(path)
        self._reader = BvaeReader(path)
        try:
            self.header = self._reader.header
            try:
                self.decoder = decoder if decoder is not None else BrdfDecoder.for_header(self.header)
            except DecoderNotFoundError as error:
                raise DecoderNotFoundError(f"{os.fspath(path)}: {error}") from None
            self.decoder.check(self.header, path)
        except BaseException:
            self._reader.close()
            raise
        self._materials: dict[str, DecodedMaterial] = {}

    def __enter__(self) -> MaterialLibrary:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the file (decoded materials stay usable)."""
        self._reader.close()

    @property
    def names(self) -> list[str]:
        """Material names in file order."""
        return self.header.names

    def __len__(self) -> int:
        return len(self.header.entries)

    def __contains__(self, name: object) -> bool:
        return name in self.header.names

    def __getitem__(self, name: str) -> DecodedMaterial:
        if name not in self._materials:
            self._materials[name] = DecodedMaterial(self._reader.read(name), self.decoder)
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


def _as_brdfs(sources: Iterable[MerlBRDF | str | os.PathLike[str]]) -> list[MerlBRDF]:
    return [s if isinstance(s, MerlBRDF) else read_merl(s) for s in sources]


def compress(
    sources: MerlBRDF | str | os.PathLike[str] | Sequence[MerlBRDF | str | os.PathLike[str]],
    output: str | os.PathLike[str] | None = None,
    *,
    model: ModelSpec = None,
    latent_dtype: LatentDtype = "float32",
    measure_error: bool = True,
    overwrite: bool = False,
) -> list[Record]:
    """Encode MERL tables (objects or file paths) and optionally write them as one ``.bvae`` file.

    Parameters
    ----------
    sources : MerlBRDF, path, or a sequence of them
    output : path, optional
        Where to write the ``.bvae`` file (atomically).
    model : model folder, decoder SHA-256, or None for the default
    latent_dtype : {"float32", "float16"}
    measure_error : bool, default True
        Decode each record and store its RelAE against the source in ``meta``.
    overwrite : bool, default False

    Returns
    -------
    list of LatentRecord
    """
    items = [sources] if isinstance(sources, MerlBRDF | str | os.PathLike) else list(sources)
    brdfs = [prepare_source(b) for b in _as_brdfs(items)]
    encoder = BrdfEncoder(model)
    records: list[Record] = list(encoder.encode_many(brdfs))
    if measure_error:
        decoder = BrdfDecoder(encoder.manifest)
        records = [measure(r, decoder, b) for r, b in zip(records, brdfs, strict=True)]
    if output is not None:
        write_bvae(output, records, encoder.reference, latent_dtype=latent_dtype, overwrite=overwrite)
    return records


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
        Stored MERL units; see :meth:`BrdfDecoder.table`.
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

