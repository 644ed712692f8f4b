"""Encoding with effort and rate control: what :class:`~brdfcodec.codec.BrdfEncoder` runs per batch."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Protocol, get_args

import numpy as np

from brdfcodec.codec.basis_operator import BasisOperator
from brdfcodec.codec.rate import (
    BasisFit,
    BasisOnlyFit,
    CompactAloneFit,
    Metric,
    MuStorage,
    coded_mu_grids,
    encode_layers,
)
from brdfcodec.codec.refine import (
    EFFORT_STEPS,
    LAYER_POLISH_PASSES,
    POLISH_PASSES,
    fit_basis_coefficients,
    fit_basis_only_coefficients,
    polish_quantised_coefficients,
    refine_latent,
)
from brdfcodec.conventions import MAPPED_MAX
from brdfcodec.format.bvae import LatentRecord, descriptor_size
from brdfcodec.format.layered_record import MU_CODED, MU_INT8_FIXED, LayeredRecord, compact_mu_values
from brdfcodec.layers.basis import (
    MAX_BASIS_COUNT,
    STEP_BYTES,
    BasisError,
    BasisLayer,
    SharedBasis,
    basis_offset,
    packed_coefficients,
    quantise_coefficients,
)
from brdfcodec.layers.basis_layer import coded_coefficients
from brdfcodec.layers.coded_basis import (
    CODED_HEADER_BYTES,
    MAX_MAGNITUDE,
    choose_coding,
    encode_integers,
    mu_stream_lead,
    prior_codes,
)
from brdfcodec.layers.packed import choose_packing, packed_step_code, packed_widths

if TYPE_CHECKING:
    from brdfcodec.io.merl import MerlBRDF
    from brdfcodec.models.network import Decoder


class LayerDecoder(Protocol):
    """What layer encoding needs of a decoder (:class:`brdfcodec.codec.BrdfDecoder` is one): its network, base
    decodes in the mapped domain, its shared basis and the projected base of ``spec/bvae-format.md`` §4.5."""

    network: Decoder

    @property
    def shared_basis(self) -> SharedBasis | None: ...

    @property
    def projection_centre(self) -> np.ndarray: ...

    def decode_mapped(self, codes: np.ndarray) -> np.ndarray: ...

    def project_base(self, record: LayeredRecord, mapped: np.ndarray) -> None: ...

__all__ = [
    "PROJECTED_BASE_VECTORS", "BasisCoding", "EncodeOptions", "LatentChoice", "ProjectBase", "layer_records",
    "projected_base_vectors",
]

#: Basis vectors a writer projects a layered record's base decode on (``layers.basis.project``, format 1.6) when
#: asked to (``EncodeOptions.project_base``). The decoder's output carries what its 8 numbers say about a material
#: in the leading principal components; past them it adds its own errors, larger on new materials than the mean's.
#: On materials the model was not trained on, projecting on more vectors than these gains no more at small budgets,
#: and every vector costs decode time: the projection runs after the network and needs a pass over the vectors,
#: taken on the factors of a factorised basis (documentation: Layers and rate control).
PROJECTED_BASE_VECTORS = 50

#: When a writer projects a layered record's base (:class:`EncodeOptions`): ``"auto"`` fits the basis layer both
#: ways and keeps, per material and size, the one with the lower kept-slice error (records without a detail layer
#: only); ``"always"``; ``"never"``.
ProjectBase = Literal["auto", "always", "never"]
_PROJECT_BASE_CHOICES: tuple[str, ...] = get_args(ProjectBase)

#: Whether rate control may write records without a latent (format 2.1, :class:`EncodeOptions`): ``"always"`` (the
#: default since issue 48) writes a latent in every record, so every record can be edited; ``"auto"`` makes records
#: without one candidates beside the latent ones wherever the model has a shared basis and a linear path covering
#: it, and keeps whichever has the lower error (a latent on a tie): those records cannot be edited.
LatentChoice = Literal["auto", "always"]
_LATENT_CHOICES: tuple[str, ...] = get_args(LatentChoice)

#: How the records of rate control without a detail layer store their basis coefficients (:class:`EncodeOptions`):
#: ``"auto"`` (the default) makes a packed and a coded layer in the same bytes (of one fit where they keep as many
#: coefficients, else of a fit each) and keeps the one of lower kept-slice error (packed on a tie: readable by
#: 2.3 readers); ``"coded"`` (format 2.4, ``spec/bvae-format.md`` §4.8: one step, integers arithmetic-coded under
#: the form's Laplace prior, :data:`CODED_PRIOR`), ``"packed"`` (format 2.3, ``spec/bvae-format.md`` §4.7: one
#: step, fewer bits for later vectors, so the bytes of k int8 coefficients hold more of them) or ``"int8"`` (a float16 step and one byte each, as before
#: 2.3). Records with a detail layer store int8.
BasisCoding = Literal["auto", "coded", "packed", "int8"]

#: The Laplace prior a coded layer declares (amplitude A, decay d: vector n's spread 2^(A/16 − 4)·n^(−d/32) mapped
#: units), by whether the record has a latent: a latent base leaves a smaller residual on the vectors past the
#: decoder's linear path (spread about 2^5.7·n^−0.86) than the linear-path mean leaves on the basis' first vectors
#: (2^7.9·n^−1.27): power laws fitted to the least-squares coefficients of the seven analytic presets' residuals
#: (with a refined latent: vectors 9 to 75; without: 1 to 75) on the shipped model.
CODED_PRIOR: dict[bool, tuple[int, int]] = {True: (156, 28), False: (190, 41)}
#: The priors a coded layer may declare, tried per record (the first is :data:`CODED_PRIOR`, kept on a tie): a
#: material unlike the model's training materials leaves a residual whose spread falls more slowly with the
#: vector's rank, and under a prior that expects the fast fall its larger later coefficients cost escape codes.
#: The second prior of each kind spreads 2^(32/16) = 4 times wider past the linear path (a latent base: amplitude
#: 188, vector n's spread 2^7.75·n^−0.875) or falls as n^−0.91 from the first vector (no latent: decay 29) —
#: the spreads of the never-seen family's least-squares coefficients, which at one prior cost more coefficients
#: than the bytes hold. The writer compares the priors on the least-squares coefficients of the layer's bytes
#: (squared error of the layer's sum at those bytes, :func:`~brdfcodec.layers.coded_basis.choose_coding`) and
#: fits the layer under the better one; each prior used in a file is a form of its own (spec §3.2, §4.8).
CODED_PRIORS: dict[bool, tuple[tuple[int, int], ...]] = {True: ((156, 28), (188, 28)), False: ((190, 41), (190, 29))}
#: The first default grid exponent g (the only one above :data:`CODED_MU_COARSER_BUDGET` and under error targets) of
#: the records whose μ is entropy-coded in the coded basis layer (format 2.5, spec §4.9, μ = q · 2^−g), offered by
#: rate control beside the fixed grid's 8 bytes (:attr:`EncodeOptions.coded_mu_step`,
#: 0: none). Under the unit Laplace prior a held-out material's μ (D = 8) codes to about 5 bytes in the layer's
#: stream at g = 3; the layer refitted to the coarser μ makes up most of what the grid loses. Rows at 16 and 32 B:
#: ``reports/results/rd-*-coded-mu-*.jsonl``; the grids compared (``"coded_mu_step"`` of a ``bvae bench rd``
#: experiment, CV fold 1 at 16 and 32 B): ``reports/results/rd-cv3-fold1-b200-always-mu-grid.jsonl``.
CODED_MU_STEP_LOG2: int = 3
#: The grids of the coded-μ candidates rate control offers by default under a size budget of at most
#: :data:`CODED_MU_COARSER_BUDGET` bytes (:attr:`EncodeOptions.coded_mu_grids`): 2^−3 and the next coarser, 2^−2,
#: each a pool of candidates of its own, the one of least kept-slice error kept per material (the grid is the
#: form's ``mu step``, spec §3.2: nothing else changes in the file). Measured on CV fold 1 at 16 and 32 B, and what the
#: second grid's forms cost a library at 16 B: ``reports/results/rd-cv3-fold1-b200-always-mu-grids.jsonl``
#: (docs/results.md, "The coded μ on two grids").
CODED_MU_STEPS_LOG2: tuple[int, ...] = (CODED_MU_STEP_LOG2, CODED_MU_STEP_LOG2 - 1)
#: The largest size budget (bytes) under which the default offers the coarser grid too: where μ's bytes are a large
#: share of the record, and where it was measured. Above it its records of at most this size only, up to
#: :data:`CODED_MU_COARSER_REACH`; above that, and under an error target, 2^−3 alone: a second pool of candidates
#: costs encode time (benchmarks ``encode-64B-coded-mu`` and ``encode-32B-coded-mu-grids``).
CODED_MU_COARSER_BUDGET: int = 32
#: The largest size budget (bytes) under which the default keeps the coarser grid's records of at most
#: :data:`CODED_MU_COARSER_BUDGET` bytes among the candidates (:attr:`EncodeOptions.coded_mu_caps`), so that a budget
#: a byte above it does not lose a record it gave: on CV fold 1, ``--bytes 33`` returned records of 1–3 % more
#: kept-slice error than ``--bytes 32`` on 2 of 4 MERL-family materials, and from 36 bytes the finer grid's larger
#: records were better on all four (docs/results.md, "The coded μ's grids past 32 B").
CODED_MU_COARSER_REACH: int = 40
_BASIS_CODINGS: tuple[str, ...] = get_args(BasisCoding)

#: Most coefficients whose count takes one varint byte in a record's descriptor.
_ONE_BYTE_COUNT = 127


def _layer_size(count_in: Callable[[int, int], int], k: int, available: int) -> tuple[int, int]:
    """How many coefficients a packed or coded layer in the bytes of k int8 coefficients keeps, and the bytes
    (step and coefficients) it may take: ``(count, layer_bytes)``.

    ``count_in(available, layer_bytes)`` is the count the layer keeps of the leading ``available`` coefficients
    in ``layer_bytes``. The count's varint in the record's descriptor takes one byte up to 127 and two beyond: where
    k's takes one (k < 128), a layer of more than 127 coefficients has one byte less for them, and is kept only
    where it still keeps more than 127 (a basis larger than 128 vectors, from about 64 B).
    """
    layer_bytes = STEP_BYTES + k
    if k > _ONE_BYTE_COUNT:
        return count_in(min(available, MAX_BASIS_COUNT), layer_bytes), layer_bytes
    count = count_in(min(available, _ONE_BYTE_COUNT), layer_bytes)
    if available > _ONE_BYTE_COUNT and count == _ONE_BYTE_COUNT:
        more = count_in(min(available, MAX_BASIS_COUNT), layer_bytes - 1)
        if more > _ONE_BYTE_COUNT:
            return more, layer_bytes - 1
    return count, layer_bytes


def projected_base_vectors(decoder: LayerDecoder, basis: SharedBasis) -> int:
    """How many vectors brdfcodec's writer projects a layered base on: :data:`PROJECTED_BASE_VECTORS` (at most
    the basis' size), or 0 when the decoder has no linear-path mean over the basis' entries to centre it on."""
    try:
        _ = decoder.projection_centre
    except BasisError:
        return 0
    return min(PROJECTED_BASE_VECTORS, basis.count)


@dataclass(frozen=True)
class EncodeOptions:
    """How hard to encode and what to aim for.

    Attributes
    ----------
    effort : int
        0 to 3: Adam steps of latent refinement (0: the encoder's μ).
    bytes_budget : int, optional
        Largest record payload per material (base + detail layer).
    max_relae : float, optional
        Largest RelAE of the decoded table against its source.
    metric : {"mapped", "linear"}
        RelAE used by ``max_relae``.
    detail_step : float, optional
        A fixed detail quantisation step (mapped units) instead of a target.
    latent_itemsize : int
        Bytes per stored latent value (4 for float32 files, 2 for float16).
    basis : bool
        Whether layered records may use the model's shared basis (when it has one).
    project_base : {"auto", "always", "never"}
        Whether a record with a basis layer projects its base decode on the basis (format 1.6,
        :data:`PROJECTED_BASE_VECTORS`; :data:`ProjectBase`). On materials the model was not trained on,
        projecting lowers the mean error at small budgets, but not on every material (documentation: Layers and
        rate control), so ``"auto"`` (the default) fits both on each material
        and keeps the lower error, in records without a detail layer (with one, a projected record decodes
        past the 1.5× decode-time target of the ``decode-layered`` benchmark);
        it doubles the basis layer's fitting time. ``True`` and ``False`` mean ``"always"`` and ``"never"``.
    latent : {"always", "auto"}
        ``"always"`` (the default, issue 48): every record keeps an editable latent code. ``"auto"``: a size
        budget or an error target may pick a record without a latent (format 2.1: the decoder's linear-path mean
        plus basis coefficients from the first vector), where its error is lower (:data:`LatentChoice`); such a
        record decodes but cannot be edited, traversed, interpolated or grafted. Nothing changes without a
        target, or without a shared basis.
    store_sigma : bool
        Store σ (False, the default: μ alone, format 2.2; rate control gives σ's bytes to the layers).
    basis_coding : {"auto", "coded", "packed", "int8"}
        How the records of rate control (a size budget or an error target) without a detail layer store basis
        coefficients (:data:`BasisCoding`; default ``"auto"``: per record, packed, format 2.3, or coded, format
        2.4, in the same bytes, whichever has the lower kept-slice error; ``"packed"`` or ``"coded"`` alone;
        ``"int8"``).
    coded_mu_step : int, tuple of int or None
        The grid exponents g, each 1 to :data:`~brdfcodec.layers.coded_basis.MAX_MU_STEP_LOG2`, of the candidate
        records whose μ is entropy-coded in the coded basis layer (format 2.5, μ = q·2^−g; :attr:`coded_mu_grids`
        says when they are offered), each grid a pool of candidates of its own; one integer g: that grid alone;
        0 or (): none; None (the default): :data:`CODED_MU_STEPS_LOG2` under a size budget of at most
        :data:`CODED_MU_COARSER_BUDGET` bytes, and up to :data:`CODED_MU_COARSER_REACH` with the coarser grid's
        records capped at :data:`CODED_MU_COARSER_BUDGET` bytes (:attr:`coded_mu_caps`), else
        :data:`CODED_MU_STEP_LOG2` alone. Stored as a tuple (None as None).
    """

    effort: int = 1
    bytes_budget: int | None = None
    max_relae: float | None = None
    metric: Metric = "mapped"
    detail_step: float | None = None
    latent_itemsize: int = 4
    basis: bool = True
    project_base: ProjectBase = "auto"
    latent: LatentChoice = "always"
    store_sigma: bool = False
    basis_coding: BasisCoding = "auto"
    coded_mu_step: int | tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        if self.coded_mu_step is not None:
            object.__setattr__(self, "coded_mu_step", coded_mu_grids(self.coded_mu_step))
        if self.basis_coding not in _BASIS_CODINGS:
            raise ValueError(f"basis_coding must be one of {list(_BASIS_CODINGS)}, got {self.basis_coding!r}")
        if self.latent not in _LATENT_CHOICES:
            raise ValueError(f"latent must be one of {list(_LATENT_CHOICES)}, got {self.latent!r}")
        if isinstance(self.project_base, bool):
            object.__setattr__(self, "project_base", "always" if self.project_base else "never")
        if self.project_base not in _PROJECT_BASE_CHOICES:
            raise ValueError(f"project_base must be one of {list(_PROJECT_BASE_CHOICES)}, got {self.project_base!r}")
        if self.effort not in EFFORT_STEPS:
            raise ValueError(f"effort must be one of {sorted(EFFORT_STEPS)}, got {self.effort!r}")
        targets = [x for x in (self.bytes_budget, self.max_relae, self.detail_step) if x is not None]
        if len(targets) > 1:
            raise ValueError("give at most one of bytes (size budget), max_relae (error target) or detail_step")
        if self.bytes_budget is not None and self.bytes_budget < 1:
            raise ValueError(f"the size budget must be a positive number of bytes, got {self.bytes_budget}")
        if self.max_relae is not None and not (np.isfinite(self.max_relae) and self.max_relae > 0):
            raise ValueError(f"max_relae must be a positive number, got {self.max_relae}")
        if self.metric not in ("mapped", "linear"):
            raise ValueError(f"metric must be 'mapped' or 'linear', got {self.metric!r}")

    @property
    def packed(self) -> bool:
        """Whether records without a detail layer pack their basis layer (``"packed"`` under a size budget or an
        error target)."""
        return self.basis_coding != "int8" and (self.bytes_budget is not None or self.max_relae is not None)

    @property
    def coded_mu_grids(self) -> tuple[int, ...]:
        """The grid exponents g of the coded-μ candidates rate control offers (format 2.5), () where it offers
        none: :attr:`coded_mu_step` where records are packed or coded under a target and coded layers are
        allowed."""
        if not (self.packed and self.basis_coding in ("auto", "coded")):
            return ()
        if self.coded_mu_step is None:  # the coarser grid's small records stay candidates a little above its budgets
            small = self.bytes_budget is not None and self.bytes_budget <= CODED_MU_COARSER_REACH
            return CODED_MU_STEPS_LOG2 if small else (CODED_MU_STEP_LOG2,)
        assert isinstance(self.coded_mu_step, tuple)  # __post_init__
        return self.coded_mu_step

    @property
    def coded_mu_caps(self) -> dict[int, int]:
        """The largest record size (bytes) of a grid's coded-μ candidates where it is below the budget: by default,
        under budgets from :data:`CODED_MU_COARSER_BUDGET` + 1 to :data:`CODED_MU_COARSER_REACH` bytes, the coarser
        grid's records of at most :data:`CODED_MU_COARSER_BUDGET` bytes (the ones a budget of that size offers);
        else none."""
        grids = self.coded_mu_grids
        if self.coded_mu_step is not None or self.bytes_budget is None or len(grids) < 2:
            return {}
        if self.bytes_budget <= CODED_MU_COARSER_BUDGET:
            return {}
        return {grid: CODED_MU_COARSER_BUDGET for grid in grids[1:]}

    @property
    def coded(self) -> bool:
        """Whether those records entropy-code their basis layer (format 2.4) rather than pack it."""
        return self.packed and self.basis_coding == "coded"

    def variants(self, linear_rank: int) -> tuple[str, ...]:
        """The first basis vectors whose packed or coded layers rate control compares: after the decoder's
        linear path (``linear_rank``, which μ drives) and from vector 0 (where the decoder's output misses on
        the leading components too: on materials the model never saw, the coefficients of those first vectors are
        often worth more than the same bytes past the last one, at every size); none where there is no linear path
        or no packed layer."""
        return (str(linear_rank), "0") if self.packed and linear_rank > 0 else ()

    @property
    def layered(self) -> bool:
        """Whether records get a detail layer (a target or a step is set)."""
        return any(x is not None for x in (self.bytes_budget, self.max_relae, self.detail_step))


def layer_records(
    records: Sequence[LatentRecord],
    decoder: LayerDecoder,
    inputs: np.ndarray,
    masks: np.ndarray,
    sources: Sequence[MerlBRDF | None],
    options: EncodeOptions,
) -> list[LatentRecord]:
    """Refine the base codes of records, then add detail layers as the options ask.

    A refined record's ``mu`` is the refined code and its ``sigma`` the
    encoder's; ``meta["effort"]`` says how it was made and, with a target,
    ``meta["rate"]`` what rate control chose.
    """
    bases, base_mapped = _refined_bases(records, decoder, inputs, masks, options)
    if base_mapped is None:
        return bases
    return [_rate_controlled(bases[i], base_mapped[i], decoder, inputs[i], masks[i], sources[i], options)[0]
            for i in range(len(records))]


@dataclass(frozen=True)
class Rung:
    """One material encoded under one record budget of library allocation's ladder.

    Attributes
    ----------
    record : LatentRecord
        What rate control chose under the budget.
    record_bytes : int
        Its bytes beyond its name (payload and index descriptor: what ``--bytes`` caps).
    distortion : float
        Its kept-slice error: the mapped L1 of its clamped decode against the material's kept slices, over their
        sum (a relative error, comparable across materials).
    """

    record: LatentRecord
    record_bytes: int
    distortion: float


def layer_record_rungs(
    records: Sequence[LatentRecord],
    decoder: LayerDecoder,
    inputs: np.ndarray,
    masks: np.ndarray,
    sources: Sequence[MerlBRDF | None],
    options: EncodeOptions,
    budgets: Sequence[int],
) -> list[list[Rung]]:
    """Each record refined once, then rate-controlled under each of ``budgets`` (a size budget each, as
    ``options`` with that ``bytes_budget``): per record, a :class:`Rung` per budget it fits, in the order of the
    budgets, a budget that made the same record as a smaller one left out (library allocation,
    :mod:`~brdfcodec.codec.allocation`).

    Raises
    ------
    RateTargetError
        A record fits none of the budgets.
    """
    from brdfcodec.errors import RateTargetError

    if not budgets:
        raise ValueError("give at least one budget")
    first = dataclasses.replace(options, bytes_budget=min(budgets), max_relae=None, detail_step=None)
    bases, base_mapped = _refined_bases(records, decoder, inputs, masks, first)
    assert base_mapped is not None  # a size budget layers its records
    out: list[list[Rung]] = []
    for i in range(len(records)):
        rungs: list[Rung] = []
        failure: RateTargetError | None = None
        for budget in sorted(set(budgets)):
            try:
                record, size, distortion = _rate_controlled(
                    bases[i], base_mapped[i], decoder, inputs[i], masks[i], sources[i],
                    dataclasses.replace(first, bytes_budget=budget))
            except RateTargetError as error:  # below the smallest record: a larger rung may fit
                failure = error
                continue
            if all((size, distortion) != (rung.record_bytes, rung.distortion) for rung in rungs):
                rungs.append(Rung(record, size, distortion))  # a budget that made no other record adds nothing
        if not rungs:
            assert failure is not None
            raise failure
        out.append(rungs)
    return out


def _refined_bases(records: Sequence[LatentRecord], decoder: LayerDecoder, inputs: np.ndarray, masks: np.ndarray,
                   options: EncodeOptions) -> tuple[list[LatentRecord], np.ndarray | None]:
    """The records with their refined codes (``meta["effort"]`` set), and their clamped base decodes where the
    options layer them (else None)."""
    mu = np.stack([r.mu for r in records])
    codes = _as_stored(refine_latent(decoder.network, mu, inputs, masks, options.effort), options.latent_itemsize)
    bases = [LatentRecord(record.name, codes[i], record.sigma, {**record.meta, "effort": options.effort})
             for i, record in enumerate(records)]
    return bases, decoder.decode_mapped(codes) if options.layered else None


def _rate_controlled(base: LatentRecord, base_mapped: np.ndarray, decoder: LayerDecoder, inputs: np.ndarray,
                     masks: np.ndarray, source: MerlBRDF | None,
                     options: EncodeOptions) -> tuple[LatentRecord, int, float]:
    """One material's record under the options' target (``meta["rate"]`` saying what rate control chose), its
    bytes beyond its name, and its kept-slice relative error (NaN where rate control measured none)."""
    basis = decoder.shared_basis if options.basis else None
    if options.max_relae is not None and source is None:
        raise ValueError(f"{base.name}: --max-relae needs the source table to measure the error")
    result = encode_layers(
        base, base_mapped, inputs, masks,
        values=None if source is None else source.values,
        mask=None if source is None else source.mask,
        bytes_budget=options.bytes_budget, max_relae=options.max_relae, metric=options.metric,
        step=options.detail_step, latent_itemsize=options.latent_itemsize,
        basis_fit=None if basis is None else _basis_fit(decoder, basis, base, inputs, masks, options),
        basis_count=0 if basis is None else basis.count,
        basis_only_fit=None if basis is None else _basis_only_fit(decoder, basis, inputs, masks, options),
        store_sigma=options.store_sigma,
        basis_variants=() if basis is None else options.variants(
            decoder.network.config.latent_dim if decoder.network.config.linear_basis else 0),
        compact_alone_fit=_compact_alone_fit(decoder, base),
        coded_mu_steps=options.coded_mu_grids,
        coded_mu_caps=options.coded_mu_caps,
    )
    chosen = result.record
    # record_bytes: what the budget caps (payload and index descriptor); payload_bytes: the payload alone
    rate = {"payload_bytes": result.payload_bytes - descriptor_size(chosen), "record_bytes": result.payload_bytes,
            "candidates_tried": len(result.tried)}
    if options.bytes_budget is not None:
        rate["bytes_budget"] = options.bytes_budget
    if options.max_relae is not None:
        rate["max_relae"] = options.max_relae
        rate["metric"] = options.metric
    new_meta = {**chosen.meta, "rate": rate}
    return dataclasses.replace(chosen, meta=new_meta), result.payload_bytes, result.distortion


def _compact_alone_fit(decoder: LayerDecoder, base: LatentRecord) -> CompactAloneFit:
    """The base's μ as a compact form stores it, and its clamped decode (the base alone, no layer: rate control's
    smallest record with a latent)."""

    def fit(storage: str) -> tuple[np.ndarray, np.ndarray]:
        code = compact_mu_values(base.mu, storage == MU_INT8_FIXED, f"{base.name}: mu")
        return code, decoder.decode_mapped(code)

    return fit


def _as_stored(codes: np.ndarray, itemsize: int) -> np.ndarray:
    """Codes rounded as the file will store them (layers code what the stored code decodes to)."""
    return codes.astype(np.float16).astype(np.float32) if itemsize == 2 else codes.astype(np.float32)


def _basis_only_fit(
    decoder: LayerDecoder, basis: SharedBasis, inputs: np.ndarray, masks: np.ndarray, options: EncodeOptions
) -> BasisOnlyFit | None:
    """The fit of one material's records without a latent (format 2.1) for
    :func:`~brdfcodec.codec.rate.encode_layers`, or None where they are off (``latent="always"``) or the
    decoder has no linear-path mean over the basis' entries to start from.

    k coefficients on the vectors 0 … k − 1: least squares, then Adam on the mapped L1 error
    (:func:`~brdfcodec.codec.refine.fit_basis_only_coefficients`), quantised as every basis layer (s = max |c| /
    127 in float16), then the integers polished on the same error
    (:func:`~brdfcodec.codec.refine.polish_quantised_coefficients`).
    """
    if options.latent != "auto":
        return None
    try:
        centre = decoder.projection_centre
    except BasisError:
        return None
    on_basis = basis.entry_mask
    target = np.asarray(inputs, dtype=np.float32).reshape(-1)[on_basis]
    weights = np.asarray(masks, dtype=np.float32).reshape(-1)[on_basis]

    def fit(k: int) -> tuple[BasisLayer, np.ndarray]:
        if options.packed:
            return fit_packed(k)
        components = BasisOperator.of(basis, 0, k)
        coefficients = fit_basis_only_coefficients(target, weights, centre, components, options.effort)
        layer = quantise_coefficients(basis.sha256, coefficients)
        if POLISH_PASSES[options.effort]:
            q = polish_quantised_coefficients(layer.step, layer.q, target, weights, centre, components,
                                              POLISH_PASSES[options.effort])
            layer = BasisLayer(basis.sha256, layer.step, q)
        return layer, basis.on_grid(centre + basis.weighted_sum(layer.coefficients()))

    def fit_packed(k: int) -> tuple[BasisLayer, np.ndarray]:
        # in the bytes of k int8 coefficients: the count the least-squares coefficients pack to, then those fitted
        # (Adam), packed or coded, and the integers polished within their fields or bytes
        least_squares_of: dict[int, np.ndarray] = {}
        prior_of: dict[int, tuple[int, int]] = {}  # the prior chosen for each size of layer tried

        def count_in(available: int, layer_bytes: int) -> int:
            if available not in least_squares_of:
                least_squares_of[available] = fit_basis_only_coefficients(
                    target, weights, centre, BasisOperator.of(basis, 0, available), 0)
            if not options.coded:
                return _packed_count(least_squares_of[available], 0, layer_bytes)
            prior_of[layer_bytes], count = _coded_prior_and_count(least_squares_of[available], 0, layer_bytes - 1,
                                                                  CODED_PRIORS[False])
            return count

        count, layer_bytes = _layer_size(count_in, k, basis.count)
        max_bytes = layer_bytes - (1 if options.coded else 0)
        components = BasisOperator.of(basis, 0, count)
        coefficients = fit_basis_only_coefficients(target, weights, centre, components, options.effort)
        if options.coded:
            layer = coded_coefficients(basis.sha256, coefficients, max_bytes, prior_of[layer_bytes])
        else:
            layer = packed_coefficients(basis.sha256, coefficients, max_bytes)
        assert layer is not None
        layer = _polished_layer(layer, target, weights, centre, basis, max_bytes, POLISH_PASSES[options.effort])
        return layer, basis.on_grid(centre + basis.weighted_sum(layer.coefficients()))

    return fit


def _basis_fit(
    decoder: LayerDecoder, basis: SharedBasis, base: LatentRecord, inputs: np.ndarray, masks: np.ndarray,
    options: EncodeOptions,
) -> BasisFit:
    """The basis fit of one material for :func:`~brdfcodec.codec.rate.encode_layers`."""

    config = decoder.network.config
    linear_rank = config.latent_dim if config.linear_basis else 0

    joint: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
    project = projected_base_vectors(decoder, basis) if options.project_base != "never" else 0
    ways = [project] if options.project_base == "always" or not project else [0, project]
    target, weights = np.asarray(inputs, dtype=np.float32), np.asarray(masks, dtype=np.float32)
    # what the polish of every packed or coded candidate measures against, taken once per material
    target_on_basis, weights_on_basis = target.reshape(-1)[basis.entries], weights.reshape(-1)[basis.entries]
    made: dict[tuple[int, tuple[MuStorage, int], int, bool, int],
               tuple[LatentRecord, BasisLayer | None, np.ndarray]] = {}
    least_squares_of: dict[tuple[int, int, int], np.ndarray] = {}
    projected_as: dict[tuple[int, tuple[MuStorage, int]], int] = {}  # the projection the first variant kept,
    # per size and μ storage (with a coded μ's grid)

    def least_squares(first: int, available: int, p: int) -> np.ndarray:
        if (first, available, p) not in least_squares_of:
            projection = None if not p else (BasisOperator.of(basis, 0, p), decoder.projection_centre)
            least_squares_of[first, available, p] = fit_basis_coefficients(
                decoder.network, base.mu[None], inputs[None], masks[None], BasisOperator.of(basis, first, available),
                basis.entries, 0, projection=projection)[1][0]
        return least_squares_of[first, available, p]

    def fit_one(k: int, mu_storage: MuStorage, p: int, packed: bool, start: int,
                grid: int) -> tuple[LatentRecord, BasisLayer | None, np.ndarray]:
        projection = None if not p else (BasisOperator.of(basis, 0, p), decoder.projection_centre)
        # Each coding asked for: the bytes of its layer and how many coefficients it keeps. --basis-coding auto makes
        # a packed and a coded layer, of one fit where they keep as many coefficients (from about 64 B: all), else
        # of a fit each, and keeps the lower error (packed first: kept on a tie, readable by 2.3 readers).
        coded_mu = mu_storage == MU_CODED  # μ rides in the coded layer's stream (format 2.5): coded layers only
        lead = None if not coded_mu else coded_mu_on_grid(base.mu, grid)
        if packed:  # in the bytes of k int8 coefficients: as many as the least-squares coefficients pack to
            first = min(start, basis.count - 1)
            codings = ["packed", "coded"] if options.basis_coding == "auto" else [
                "coded" if options.coded else "packed"]
            if coded_mu:
                codings = ["coded"]
            max_bytes, count_of = {}, {}
            prior_of: dict[int, tuple[int, int]] = {}  # a coded layer's prior for each size of layer tried
            coded_prior = CODED_PRIOR[True]  # the prior of the coded layer's size, once chosen
            for c in codings:
                def count_in(available: int, layer_bytes: int, coding: str = c) -> int:
                    if coding != "coded":
                        return _packed_count(least_squares(first, available, p), first, layer_bytes)
                    prior_of[layer_bytes], count = _coded_prior_and_count(
                        least_squares(first, available, p), first, layer_bytes - 1, CODED_PRIORS[True], lead)
                    return count
                try:
                    count_of[c], layer_bytes = _layer_size(count_in, k, basis.count - first)
                except ValueError:  # no coded layer fits these bytes: under auto, the packed one alone
                    if options.basis_coding != "auto" and not coded_mu:
                        raise
                    continue
                max_bytes[c] = layer_bytes - (1 if c == "coded" else 0)
                if c == "coded":
                    coded_prior = prior_of[layer_bytes]
            codings = [c for c in codings if c in count_of]
        else:
            first = basis_offset(linear_rank, basis.count, k)
            codings, count_of = ["int8"], {"int8": k}
        made_layers = []
        for count in dict.fromkeys(count_of.values()):
            components = BasisOperator.of(basis, first, count)
            if (first, count, p) not in joint:
                joint[first, count, p] = fit_basis_coefficients(
                    decoder.network, base.mu[None], inputs[None], masks[None], components, basis.entries,
                    options.effort, projection=projection,
                )
            codes, coefficients = joint[first, count, p]
            if mu_storage is not None:
                # μ as a compact record stores it (int8 on the fixed grid or with a step, or entropy-coded on the
                # grid 2^−g), then the coefficients refitted to that code.
                code = (coded_mu_values(codes[0], grid) if coded_mu else
                        compact_mu_values(codes[0], mu_storage == MU_INT8_FIXED, f"{base.name}: mu"))
                _, coefficients = fit_basis_coefficients(
                    decoder.network, code[None], inputs[None], masks[None], components, basis.entries,
                    options.effort, fit_latent=False, projection=projection,
                )
            else:
                code = _as_stored(codes, options.latent_itemsize)[0]
            record = LatentRecord(base.name, code, base.sigma, base.meta)
            base_mapped: np.ndarray | None = None
            for coding in (c for c in codings if count_of[c] == count):
                if coding == "coded":
                    layer = coded_coefficients(
                        basis.sha256, coefficients[0], max_bytes[coding], coded_prior, first, p,
                        coded_mu=None if not coded_mu else coded_mu_on_grid(code, grid))
                elif coding == "packed":
                    layer = packed_coefficients(basis.sha256, coefficients[0], max_bytes[coding], first, p)
                else:
                    layer = quantise_coefficients(basis.sha256, coefficients[0], first, p)
                if layer is None:  # every coefficient rounds to 0 in these bytes (the fit may find none best)
                    continue
                if base_mapped is None:
                    base_mapped = decoder.decode_mapped(code)
                    decoder.project_base(LayeredRecord(base.name, code, base.sigma, base.meta, basis=layer),
                                         base_mapped)
                if coding != "int8":
                    layer = _polished_layer(layer, target_on_basis, weights_on_basis,
                                            base_mapped.reshape(-1)[basis.entries], basis, max_bytes[coding],
                                            LAYER_POLISH_PASSES[options.effort])
                made_layers.append((codings.index(coding),
                                    (record, layer, base_mapped + basis.residual(layer.coefficients(), first))))
        if not made_layers:  # no layer at all: the candidate is the base (encode_layers' stage for k = 0)
            return base, None, decoder.decode_mapped(base.mu)
        made_layers.sort(key=lambda made: made[0])
        return min((made for _, made in made_layers), key=lambda made: kept_slice_error(made[2]))

    def kept_slice_error(mapped: np.ndarray) -> float:
        """What rate control ranks candidates by: the clamped decode's L1 error over valid kept-slice entries."""
        return float((np.abs(np.clip(mapped, 0.0, MAPPED_MAX) - target) * weights).sum())

    def fit(k: int, mu_storage: MuStorage, under_detail: bool, variant: str | None = None, *,
            grid: int = 0) -> tuple[LatentRecord, BasisLayer | None, np.ndarray]:
        # variant: the first vector of a packed or coded layer (one of options.variants(...), rate control
        # comparing them); None: after the decoder's linear path. grid: a coded μ's grid exponent g (μ = q·2^−g),
        # with mu_storage MU_CODED.
        # "auto" projects only records without a detail layer: with one, the projection's pass over the vectors
        # and the detail layer's inverse DCT both follow the network, and together they take the decode past the
        # 1.5x a base-only one that a layered decode may take (benchmark decode-layered).
        chosen = [0] if under_detail and options.project_base == "auto" else ways
        packed = options.packed and not under_detail
        start = linear_rank if variant is None else int(variant)
        if mu_storage == MU_CODED and not grid:
            raise ValueError("a coded μ needs its grid exponent")
        storage = (mu_storage, grid if mu_storage == MU_CODED else 0)
        if packed and start != linear_rank:
            if (k, storage) not in projected_as:
                fit(k, mu_storage, under_detail, grid=grid)  # the first variant chooses the projection
            chosen = [projected_as[k, storage]]  # a later variant: the projection the first one kept
        fits = []
        for p in chosen:
            if (k, storage, p, packed, start) not in made:
                made[k, storage, p, packed, start] = fit_one(k, mu_storage, p, packed, start, storage[1])
            fits.append((made[k, storage, p, packed, start], p))
        best, p = min(fits, key=lambda candidate: kept_slice_error(candidate[0][2]))
        if packed and start == linear_rank:
            projected_as[k, storage] = p
        return best

    return fit


def coded_mu_on_grid(mu: np.ndarray, step_log2: int) -> tuple[int, np.ndarray]:
    """A coded μ's ``(g, q)`` on the grid 2^−g, g = ``step_log2`` (format 2.5): q = round(μ · 2^g)."""
    g = int(step_log2)
    return g, np.rint(np.asarray(mu, dtype=np.float64) * float(1 << g)).astype(np.int64)


def coded_mu_values(mu: np.ndarray, step_log2: int) -> np.ndarray:
    """The float32 values a coded μ on the grid 2^−g decodes to (what an encoder fits the layer to)."""
    g, q = coded_mu_on_grid(mu, step_log2)
    return (q / float(1 << g)).astype(np.float32)


def _polished_layer(layer: BasisLayer, target: np.ndarray, weights: np.ndarray, base: np.ndarray,
                    basis: SharedBasis, max_bytes: int, passes: int) -> BasisLayer:
    """A packed or entropy-coded basis layer, its integers polished on the mapped L1 error of the clamped decode
    ``clamp(base + Σ s·qᵢ bᵢ)`` over the valid entries
    (:func:`~brdfcodec.codec.refine.polish_quantised_coefficients`), within its fields (packed) or its bytes
    (coded: a move is kept only where the coder's output, with the step code, still fits ``max_bytes``).

    The layer was chosen closest to the float coefficients in squared coefficient error; the polish measures
    what rate control ranks candidates by (the L1 norm, after the clamp, on the base as decoded: a record's
    clamped and projected base decode, or the decoder's linear-path mean for a record without a latent).

    Parameters
    ----------
    layer : BasisLayer
        Packed (``top``) or coded (``prior``).
    target, weights, base : ndarray of float32, shape (E,)
        The material's mapped kept slices, their validity (0 or 1) and the base, at the basis' entries.
    basis : SharedBasis
    max_bytes : int
        A coded layer's bytes, step code included, as rate control sized it.
    passes : int
        At most this many sweeps (0: the layer as it is).
    """
    if not passes:
        return layer
    fits = None
    if layer.prior is not None:
        lead_q, lead_codes = layer.stream_codes()  # a coded μ's integers, ahead in the stream (format 2.5)
        codes = np.concatenate([lead_codes, prior_codes(layer.prior[0], layer.prior[1], packed_step_code(layer.step),
                                                        layer.first, layer.count)])
        room = max_bytes - CODED_HEADER_BYTES
        bounds = (np.full(layer.count, -MAX_MAGNITUDE), np.full(layer.count, MAX_MAGNITUDE))

        def coder_fits(q: np.ndarray) -> bool:
            return len(encode_integers(np.concatenate([lead_q, np.asarray(q, dtype=np.int64)]), codes)) <= room

        fits = coder_fits
    else:
        widths = packed_widths(layer.top, layer.first, layer.count)
        bounds = (-(1 << (widths - 1)), (1 << (widths - 1)) - 1)
    q = polish_quantised_coefficients(layer.step, layer.q, target, weights, base,
                                      BasisOperator.of(basis, layer.first, layer.count), passes, bounds=bounds,
                                      fits=fits)
    return dataclasses.replace(layer, q=np.asarray(q, dtype=np.int64))


def _coded_prior_and_count(coefficients: np.ndarray, first: int, max_bytes: int,
                           priors: Sequence[tuple[int, int]],
                           coded_mu: tuple[int, np.ndarray] | None = None) -> tuple[tuple[int, int], int]:
    """The prior (of ``priors``) under which the best coded layer of ``max_bytes`` leaves the least squared error
    of these coefficients (of vectors ``first``, …; the first prior on a tie), and how many coefficients it keeps
    (after a coded μ's integers, ``(g, q)``, when given: format 2.5).

    Raises
    ------
    ValueError
        No coded layer fits (not even one coefficient) under any of the priors.
    """
    best: tuple[float, tuple[int, int], int] | None = None
    lead = None if coded_mu is None else mu_stream_lead(coded_mu)
    for prior in priors:
        choice = choose_coding(coefficients, first, max_bytes, *prior, lead=lead)
        if choice is not None and (best is None or choice.error < best[0]):
            best = (choice.error, prior, len(choice.q))
    if best is None:
        raise ValueError(f"no coded basis layer fits in {max_bytes} bytes")
    return best[1], best[2]


def _packed_count(coefficients: np.ndarray, first: int, max_bytes: int) -> int:
    """How many of these coefficients (of vectors ``first``, …) the best packed layer of ``max_bytes`` keeps."""
    choice = choose_packing(coefficients, first, max_bytes)
    if choice is None:
        raise ValueError(f"no packed basis layer fits in {max_bytes} bytes")
    return len(choice.q)
