"""The encoder: MERL tables to latent records, and measuring a record against its source.

Part of :mod:`brdfcodec.codec`, which re-exports the public names.
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.conventions import NETWORK_INPUT_SHAPE
from brdfcodec.format.bvae import (
    DecoderReference,
    GraftRecord,
    LatentDtype,
    LatentRecord,
    Record,
    record_size,
)
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.io.merl import MerlBRDF, source_digest
from brdfcodec.models.store import ModelManifest, load_model
from brdfcodec.representation import (
    network_input_from_table,
    to_network_layout,
)
from brdfcodec.representation.mask import kept_slice_horizon_mask
from brdfcodec.representation.metrics import NEAR_BLACK_REFLECTANCE, relae_both
from brdfcodec.runtime.threads import codec_threads

if TYPE_CHECKING:
    from brdfcodec.codec.encoding import BasisCoding, LatentChoice, ProjectBase, Rung

from brdfcodec.codec.black import black_record, is_near_black_source
from brdfcodec.codec.decoder import BrdfDecoder, _EvalMode
from brdfcodec.codec.devices import indexed_device
from brdfcodec.codec.prepare import ModelSpec, prepare_source, resolve_model

__all__ = ["BrdfEncoder", "MaterialInput", "measure"]


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
        (documentation: Layers and rate control).
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
        error at equal size on most materials, a slower decode (documentation: Layers and rate control).
        ``"auto"`` fits both and keeps
        the better per material; ``True``/``False`` mean ``"always"``/``"never"``. Ignored where the model's
        decoder has no linear path to centre the projection on.
    latent : {"always", "auto"}, default "always"
        With ``bytes`` or ``max_relae``: ``"always"`` (the default, issue 48): every record keeps a latent code
        that edits can move. ``"auto"`` lets rate control pick a record without a latent (format 2.1, the
        decoder's linear-path mean plus basis coefficients) where its error is lower; it decodes like any other
        but cannot be edited.
    store_sigma : bool, default False
        Store the posterior width σ. By default a record stores μ alone (format 2.2, ``layers.sigma = "none"``:
        half a plain record's payload; under a size budget its bytes go to the layers) and reads back with
        σ = 1: the shipped model's σ says nothing about how certain an encoding is (its model card, "The
        posterior width σ").
    basis_coding : {"auto", "packed", "coded", "int8"}, default "auto"
        With ``bytes`` or ``max_relae``: how records without a detail layer store their basis
        coefficients. ``"auto"`` makes both a packed and a coded layer in the same bytes and keeps the one of
        lower error (packed on a tie). ``"packed"`` (format 2.3) gives later basis vectors fewer bits at one
        step, so a budget holds more coefficients; ``"coded"`` (format 2.4) arithmetic-codes them at one step under a
        Laplace prior whose spread falls with the vector's rank; ``"int8"`` stores one byte each (readable by
        2.2 readers).
    coded_mu_step : int or tuple of int, optional
        With ``bytes`` or ``max_relae`` and ``basis_coding`` ``"auto"`` or ``"coded"``: the grid exponents g, each
        1 to 5, of the candidate records whose μ is entropy-coded in the coded basis layer (format 2.5,
        μ = q·2^−g), offered beside the compact forms, each grid a pool of candidates of its own (the record
        of least kept-slice error kept); one integer: that grid alone; 0 offers none. By default 2^−3 and 2^−2
        (:data:`~brdfcodec.codec.encoding.CODED_MU_STEPS_LOG2`) under ``bytes`` of at most
        :data:`~brdfcodec.codec.encoding.CODED_MU_COARSER_BUDGET`, 2^−2's records of at most that size beside
        2^−3's under ``bytes`` up to :data:`~brdfcodec.codec.encoding.CODED_MU_COARSER_REACH` (so that a byte
        more never loses them), else 2^−3 alone.
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
        latent: LatentChoice = "always",
        store_sigma: bool = False,
        basis_coding: BasisCoding = "auto",
        coded_mu_step: int | tuple[int, ...] | None = None,
    ) -> None:
        from brdfcodec.codec.encoding import EncodeOptions

        self.options = EncodeOptions(
            effort=effort, bytes_budget=bytes, max_relae=max_relae, metric=metric, detail_step=detail_step,
            latent_itemsize=2 if latent_dtype == "float16" else 4, basis=basis, project_base=project_base,
            latent=latent, store_sigma=store_sigma, basis_coding=basis_coding,
            coded_mu_step=coded_mu_step,
        )
        manifest = resolve_model(model)
        network, _, loaded = load_model(manifest.folder, parts=("encoder",), device=str(device))
        if network is None:  # load_model returns the parts asked for
            raise RuntimeError(f"{manifest.folder}: the encoder did not load")
        self._setup(network, device, loaded)

    def _setup(self, network: torch.nn.Module, device: str | torch.device, manifest: ModelManifest | None) -> None:
        self.network = network
        self.device = indexed_device(device)  # cuda → cuda:N, as its tensors' .device
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
        black = {}  # near-black sources decode black (issue 49), where such a record fits the budget
        for i, source in enumerate(sources):
            made = black_record(records[i], store_sigma=self.options.store_sigma,
                                bytes_budget=self.options.bytes_budget,
                                latent_dtype="float16" if self.options.latent_itemsize == 2 else "float32",
                                ) if is_near_black_source(source) else None
            if made is not None:
                black[i] = made
        lit = [i for i in range(len(records)) if i not in black]
        if lit and (self.options.effort != 0 or self.options.layered):
            from brdfcodec.codec.encoding import layer_records

            with codec_threads():  # refinement and rate control: thousands of small torch operations
                layered = layer_records([records[i] for i in lit], self.decoder, inputs[lit], masks[lit],
                                        [sources[i] for i in lit], self.options)
            for i, record in zip(lit, layered, strict=True):
                records[i] = record
        for i, made in black.items():
            records[i] = made
        if self.options.store_sigma:
            return records
        # σ left out (format 2.2): a plain record becomes μ alone (rate control already left σ out of its own).
        return [LayeredRecord.code_only(r) if type(r) is LatentRecord else r for r in records]

    def encode_rungs(
        self,
        names: Sequence[str],
        inputs: np.ndarray,
        masks: np.ndarray,
        sources: Sequence[MerlBRDF | None],
        budgets: Sequence[int],
    ) -> list[list[Rung]]:
        """Per material, its records under each of ``budgets`` (record budgets in bytes, as ``bytes`` counts them):
        the ladder library allocation chooses from (:func:`~brdfcodec.codec.allocation.allocate_bytes`).

        The latent is refined once per material and rate control runs once per budget, with this encoder's options
        but the budget (its ``bytes``, ``max_relae`` or step set aside). A budget that makes the same record as a
        smaller one adds no rung; a near-black source (issue 49) has one rung, its black record, where that fits
        one of the budgets.

        Returns
        -------
        list of list of Rung
            Per material, in the order given, its rungs in the order of the budgets (at least one).

        Raises
        ------
        RateTargetError
            A material fits none of the budgets.
        """
        from brdfcodec.codec.encoding import Rung, layer_record_rungs

        mu, sigma = self.posterior_from_inputs(inputs, batch_size=max(len(inputs), 1))
        records = self.make_records(names, mu, sigma, sources)
        latent_dtype: LatentDtype = "float16" if self.options.latent_itemsize == 2 else "float32"
        out: dict[int, list[Rung]] = {}
        for i, source in enumerate(sources):
            made = next((black for budget in sorted(budgets)  # the smallest budget its black record fits
                         if (black := black_record(records[i], store_sigma=self.options.store_sigma,
                                                   bytes_budget=budget, latent_dtype=latent_dtype)) is not None),
                        None) if is_near_black_source(source) else None
            if made is not None:  # decodes exactly black: no error to trade
                out[i] = [Rung(made, record_size(made, latent_dtype), 0.0)]
        lit = [i for i in range(len(records)) if i not in out]
        if lit:
            with codec_threads():
                ladders = layer_record_rungs([records[i] for i in lit], self.decoder, inputs[lit], masks[lit],
                                             [sources[i] for i in lit], self.options, budgets)
            out.update(zip(lit, ladders, strict=True))
        return [out[i] for i in range(len(records))]

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
    :func:`prepare_source` gives it. A near-black material (every valid
    entry below ``NEAR_BLACK_REFLECTANCE``, 1e-6 /sr) has no meaningful RelAE:
    ``relae`` is then left out, with a warning (its absolute error:
    :func:`~brdfcodec.representation.metrics.mean_absolute_error`).
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
        warnings.warn(f"{where}: RelAE is undefined for a near-black material (every reflectance below "
                      f"{NEAR_BLACK_REFLECTANCE:g} /sr); not stored", stacklevel=2)
    if isinstance(record, GraftRecord):
        return GraftRecord(record.name, record.mu, record.sigma, record.graft_dims, record.graft_values, meta)
    return replace(record, meta=meta)  # the same kind: a layered record keeps its layers


