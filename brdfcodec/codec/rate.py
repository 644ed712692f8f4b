"""Layered encoding with rate control: a size budget or an error target per material.

Given a material's base code, its decode and its source, :func:`encode_layers`
chooses the enhancement layers among candidate records, each with a rate R
(bytes beyond its name: payload and descriptor) and a distortion D:

- the base alone (μ in the latent dtype) and, in records without σ (format 2.2), the base alone with μ stored
  compact (:class:`_CompactAlone`, 10 bytes for D = 8: the smallest record with a latent);
- k coefficients on the model's shared basis (:mod:`brdfcodec.layers.basis`,
  when the model has one), as many as fit, in each variant of the basis fit
  (``basis_variants``: brdfcodec's writer starts the coefficients after
  the decoder's linear path or at the first vector), on
  the base stored compact (μ as int8, :func:`compact_mu_storage`) where the
  budget cannot hold all K coefficients beside μ in the latent dtype
  (:func:`compact_base_pays`), else on the full base and on a compact one (the builder,
  :mod:`brdfcodec.codec.encoding`, polishes a packed or coded layer's integers on D before they are ranked);
- min(k, n) int8 coefficients under a detail layer, n each count of
  :data:`DETAIL_BASIS_COUNTS` for a size budget (32 and 64) and
  :data:`DETAIL_BASIS_COUNT` (32) for an error target, whose quantisation
  step comes from a fixed ladder (:data:`STEP_LADDER`, halving every two
  rungs), bisected to the finest rungs that fit, then refined between the
  two that bracket the budget.

One rate–distortion rule chooses among them (minimise D + λR, λ set by the
target):

- ``bytes_budget=N``: D is the kept-slice mapped L1 error of the clamped
  decode, and the record is the one of lowest D among the candidates of
  R ≤ N (:func:`lowest_distortion`: the Lagrangian sweep over λ,
  :func:`lagrangian_hull`, reaches the lower convex hull of the (R, D)
  points; the best fitting point of all, hull or not, is never worse than the
  best fitting hull point, and is what is kept; ties: fewer coefficients,
  the full base, the variant listed first). Every candidate measured is
  returned (:attr:`RateResult.points`). Within each kind of candidate more
  bytes lower D, so each kind offers its largest fitting member; the compact
  base's record stays a candidate past the budgets that store the base
  compact, so that a larger budget never returns a worse record than a
  smaller one (``tests/test_rate_monotone.py``). No error is traded for
  decode time; the cap of max(:data:`DETAIL_BASIS_COUNTS`) coefficients under a
  detail layer bounds every layered record's decode time (documentation:
  Layers and rate control);
- ``max_relae=X``: D is the measured RelAE (mapped or linear, full table,
  valid entries), and the record is the one of smallest R among the
  candidates measured with D ≤ X: the first of 4, 8, 16, 32 and K basis
  coefficients on a compact base (in each variant), then, if K misses X,
  min(K, :data:`DETAIL_BASIS_COUNT`) coefficients plus each rung from coarse
  to fine (:func:`error_target_sequence`), bisected (size falls and error
  rises along the sequence), the step then bisected in log space between the
  two rungs that bracket X (2 rounds); then, for each grid of ``coded_mu_steps``,
  the size of a record whose μ is entropy-coded in its layer (format 2.5) is
  bisected below that choice, and the smallest such record that meets X replaces it.

The achieved RelAE is measured on the returned record. A layered record
stores σ compactly (one byte per dimension, ``spec/bvae-format.md`` §4.5) or
not at all (format 2.2); a compact base stores μ as int8 on the fixed grid
μ = q / 32 where it fits ±3.97, else with a float16 step (σ, when stored, as
one shared byte), which makes budgets from 12 bytes possible; without σ, the base alone, μ compact and no
layer, takes 10 (D = 8, a one-byte name).

Records without a latent (format 2.1, ``spec/bvae-format.md`` §4.6) are candidates too when a
:data:`BasisOnlyFit` is given (``EncodeOptions.latent = "auto"``): k coefficients from the basis' first vector
on the decoder's linear-path mean, as many as fit the budget beside the step and the descriptor (for an error
target, the same counts as the compact base's). They are kept where their D is strictly lower (a latent on a
tie, since it can be edited), or for an error target where they are smaller. Budgets too small for any record
with a latent (from 6 bytes with a one-byte name) then hold one without.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import MAPPED_MAX, NETWORK_INPUT_SHAPE
from brdfcodec.errors import RateTargetError
from brdfcodec.format.bvae import LatentRecord, record_overhead
from brdfcodec.format.layered_record import MU_CODED, MU_INT8, MU_INT8_FIXED, LayeredRecord
from brdfcodec.layers.basis import STEP_BYTES, BasisLayer, fits_fixed_mu_grid
from brdfcodec.layers.coded_basis import MAX_MU_STEP_LOG2
from brdfcodec.layers.detail import DetailLayer, decode_detail, encode_detail
from brdfcodec.representation.metrics import RelaeAgainst
from brdfcodec.representation.network_io import table_from_network_output

__all__ = [
    "DETAIL_BASIS_COUNT", "DETAIL_BASIS_COUNTS", "STEP_LADDER", "BasisFit", "BasisOnlyFit", "CompactAloneFit", "Metric",
    "MuStorage",
    "RateResult", "RatePoint", "compact_base_pays", "compact_mu_storage",
    "encode_layers",
    "error_target_sequence", "layered_mapped", "lagrangian_hull", "lowest_distortion",
]

Metric = Literal["mapped", "linear"]
#: Quantisation steps tried, coarsest first (mapped units): 16 · 2^(−i/2), i = 0 … 28.
STEP_LADDER: Final = tuple(float(16.0 * 2.0 ** (-i / 2)) for i in range(29))
#: Log-space halvings of the step between the two rungs that bracket a target.
_REFINE_ROUNDS: Final = 3


@dataclass(frozen=True)
class RateResult:
    """The chosen record, its payload size, and what rate control tried.

    Attributes
    ----------
    record : LatentRecord or LayeredRecord
    payload_bytes : int
        What the record adds to a file beyond its name's bytes (what a size budget caps): μ, σ and the layers
        as stored, plus its descriptor in the file's index (:func:`~brdfcodec.format.bvae.record_overhead`).
    tried : list of (step or None, payload bytes, RelAE or None)
        Every candidate evaluated (None step: no detail layer).
    points : list of RatePoint
        Under a size budget: every candidate record whose rate and distortion were measured (what
        :func:`lowest_distortion` chose from); empty otherwise.
    distortion : float
        Under a size budget: the chosen record's kept-slice distortion (what the budget ranked it by) over the sum
        of the material's kept slices, a relative error that compares across materials (library allocation,
        :mod:`~brdfcodec.codec.allocation`); NaN otherwise.
    """

    record: LatentRecord
    payload_bytes: int
    tried: list[tuple[float | None, int, float | None]]
    points: list[RatePoint] = field(default_factory=list)
    distortion: float = float("nan")


@dataclass(frozen=True)
class RatePoint:
    """One candidate record of a size budget: its rate R, its distortion D and how to build it.

    Attributes
    ----------
    rate : int
        Bytes the record adds to a file beyond its name (payload and descriptor).
    distortion : float
        Kept-slice mapped L1 error of its clamped decode (sum over valid entries of the 63 × 90 × 90 slices).
    compact : bool
        Whether the base is stored compact (μ as int8).
    option : (int, float or None, str or None)
        Basis coefficients k (in int8-equivalent bytes for a packed or coded layer), detail step (None: no
        detail layer) and the basis fit's variant (None: its own); for the compact base alone (k 0, no detail
        layer, ``compact``), how μ is stored (``"int8"`` or ``"int8-fixed"``).
    pool : object
        The candidates' builder (internal).
    """

    rate: int
    distortion: float
    compact: bool
    option: tuple[int, float | None, str | None]
    pool: Any = field(repr=False, compare=False)

    @property
    def label(self) -> str:
        """A short name: ``compact-mu k=48 variant=0``, ``coded-mu g=3 k=12 variant=8``, ``mu k=32 detail=0.5``,
        ``mu alone``."""
        k, step, variant = self.option
        if not k and step is None:  # the base record: μ in the latent dtype, or compact (no layer, no σ)
            return "compact-mu alone" if self.compact else "mu alone"
        coded = getattr(self.pool, "mu_storage", None) == MU_CODED
        parts = [f"coded-mu g={self.pool.coded_mu_step}" if coded else "compact-mu" if self.compact else "mu",
                 f"k={k}"]
        if variant is not None:
            parts.append(f"variant={variant}")
        if step is not None:
            parts.append(f"detail={step:.4g}")
        return " ".join(parts)


#: How a record stores μ: None in the file's latent dtype, else compact (``layers.mu``): ``"int8"`` (a float16
#: step and D int8 values), ``"int8-fixed"`` (D int8 values on the fixed grid μ = q / 32) or ``"coded"``
#: (entropy-coded in the coded basis layer's stream, format 2.5).
MuStorage = str | None
#: What a basis fit returns for k coefficients, how μ is stored (when compact, the code it returns is the
#: quantised one, and the coefficients are fitted to it) and whether a detail layer will follow (the writer may
#: then choose differently, for decode time: :func:`~brdfcodec.codec.encoding.layer_records`): the base with its
#: jointly refined μ, the layer, and the decoder's mapped output before the detail layer (clamped base decode
#: plus the basis residual). The layer is None when no coefficient survives quantisation in those bytes (the fit
#: found no coefficients best, as it may on a material unlike the training ones): the candidate is then the base.
BasisFit = Callable[[int, MuStorage, bool], tuple[LatentRecord, BasisLayer | None, np.ndarray]]
#: What a fit of a record without a latent (format 2.1) returns for k coefficients on the basis' vectors
#: 0 … k − 1: the layer (quantised as stored) and the decode's mapped kept slices before the clamp (the decoder's
#: linear-path mean at the basis' entries plus the layer's sum).
BasisOnlyFit = Callable[[int], tuple[BasisLayer, np.ndarray]]
#: What a fit of the base alone stored compact returns (format 2.2: μ in a compact form, no σ and no layer), for
#: a storage (``"int8"`` or ``"int8-fixed"``): the code as stored and the decoder's mapped output of it, clamped.
CompactAloneFit = Callable[[str], tuple[np.ndarray, np.ndarray]]
#: Basis sizes tried by an error target below the basis' full size.
_BASIS_COUNTS: Final = (4, 8, 16, 32)
#: A candidate of an error target: compact base or not, basis coefficients, detail step (None: no detail layer).
_Candidate = tuple[bool, int, float | None]
#: The most basis coefficients a record with a detail layer carries, so that decoding any layered record stays
#: within 1.5 times its base-only decode (the basis sum reads every factor its coefficients use: the leading
#: coefficients use fewer of them than all K do). Where a detail layer has room, the bytes of further coefficients
#: buy more as detail, so the cap costs little error against also trying all K (documentation: Layers and rate
#: control).
DETAIL_BASIS_COUNT: Final = 32
#: The basis coefficients a size budget tries under a detail layer, each a candidate of its own (the rate rule keeps
#: the one of lower distortion): 32, and 64 where a budget's detail layer has room to spare, which lowers the error
#: at 2-16 KB where 32 stalled (rows ``reports/results/rd-shipped-held-out-large*.jsonl``), its decode within the
#: same 1.5 times the base (benchmark ``decode-layered``). An error target and a fixed step keep
#: :data:`DETAIL_BASIS_COUNT`.
DETAIL_BASIS_COUNTS: Final = (DETAIL_BASIS_COUNT, 64)


def layered_mapped(base_mapped: np.ndarray, record: LatentRecord) -> np.ndarray:
    """Base decode plus the record's detail layer, if any (mapped, network layout)."""
    if isinstance(record, LayeredRecord) and record.detail is not None:
        return base_mapped + decode_detail(record.detail).reshape(base_mapped.shape)
    return base_mapped


class _Candidates:
    """Records made of the base, k basis coefficients (0: none) and a detail layer at step s (None: none)."""

    def __init__(self, base: LatentRecord, base_mapped: np.ndarray, inputs: np.ndarray, masks: np.ndarray,
                 latent_itemsize: int, basis_fit: BasisFit | None, compact: bool = False,
                 fixed_grid: bool = False, store_sigma: bool = True, coded_mu_step: int = 0) -> None:
        self.base, self.inputs, self.masks = base, inputs, masks
        self.store_sigma = store_sigma
        d = base.latent_dim
        # the base alone: μ (and σ, when stored) in the latent dtype, and its descriptor
        self.plain_bytes = (2 if store_sigma else 1) * d * latent_itemsize + record_overhead(base.name)
        self.mu_storage = (MU_INT8_FIXED if fixed_grid else compact_mu_storage(base.mu)) if compact else None
        self.coded_mu_step = coded_mu_step  # g > 0: μ entropy-coded in the layer (its bytes counted there)
        if coded_mu_step:
            self.mu_storage = MU_CODED
        self.layered_bytes = _layered_base_bytes(d, latent_itemsize, self.mu_storage, store_sigma)
        self.basis_fit = basis_fit
        self.stages: dict[tuple[int, bool, str | None], tuple[LatentRecord, BasisLayer | None, np.ndarray]] = {}
        self.base_mapped = base_mapped
        self.details: dict[tuple[int, float], DetailLayer] = {}

    def stage(self, k: int, under_detail: bool = False,
              variant: str | None = None) -> tuple[LatentRecord, BasisLayer | None, np.ndarray]:
        """Base and k basis coefficients, for a record without a detail layer or (``under_detail``) with one;
        ``variant`` names the way of fitting the basis layer asked for (``basis_variants``; None: the fit's own)."""
        if k == 0:
            return self.base, None, self.base_mapped
        if (k, under_detail, variant) not in self.stages:
            assert self.basis_fit is not None
            grid: dict[str, int] = {"grid": self.coded_mu_step} if self.mu_storage == MU_CODED else {}
            fitted = (self.basis_fit(k, self.mu_storage, under_detail, **grid) if variant is None  # type: ignore[call-arg]
                      else self.basis_fit(k, self.mu_storage, under_detail, variant, **grid))  # type: ignore[call-arg]
            if fitted[1] is None:  # no coefficient survived in these bytes: the base alone, as k = 0
                fitted = (self.base, None, self.base_mapped)
            self.stages[k, under_detail, variant] = fitted
        return self.stages[k, under_detail, variant]

    def detail(self, k: int, s: float) -> DetailLayer:
        if (k, s) not in self.details:
            _, _, mapped = self.stage(k, True)
            self.details[k, s] = encode_detail((self.inputs - mapped) * self.masks, s)
        return self.details[k, s]

    def record(self, k: int, s: float | None, variant: str | None = None) -> LatentRecord:
        base, basis, _ = self.stage(k, s is not None, variant)
        if basis is None and s is None:
            return base
        detail = None if s is None else self.detail(k, s)
        storage: dict[str, bool] = {"compact_sigma": True} if self.store_sigma else {"store_sigma": False}
        sigma: dict[str, Any] = {"shared_sigma": True} if self.store_sigma else {"store_sigma": False}
        if self.mu_storage == MU_CODED:
            if basis is None or basis.prior is None:  # no coded layer to carry μ (the fit gave none)
                return base
            storage = {"coded_mu": self.coded_mu_step, **sigma}
        elif self.mu_storage is not None:
            storage = {"compact_mu": True, "fixed_mu_grid": self.mu_storage == MU_INT8_FIXED, **sigma}
        return LayeredRecord(base.name, base.mu, base.sigma, base.meta, detail=detail, basis=basis, **storage)

    def size(self, k: int, s: float | None, variant: str | None = None) -> int:
        _, basis, _ = self.stage(k, s is not None, variant)
        if basis is None and s is None:
            return self.plain_bytes
        detail = None if s is None else self.detail(k, s).nbytes
        return (self.layered_bytes + (0 if basis is None else basis.nbytes) + (detail or 0)
                + self.overhead(None if basis is None else basis.count, detail, _coded_bytes(basis)))

    def overhead(self, basis_count: int | None, detail_bytes: int | None = None,
                 basis_bytes: int | None = None) -> int:
        """The record's descriptor in the file's index (what a budget counts besides the payload; an entropy-coded
        basis layer, format 2.4, states its length there)."""
        return record_overhead(self.base.name, basis_count=basis_count, detail_bytes=detail_bytes,
                               basis_bytes=basis_bytes)

    def most_coefficients(self, bytes_budget: int, most: int) -> int:
        """The most basis coefficients (at most ``most``) whose record without a detail layer fits the budget
        with its descriptor; 0 when none does."""
        fixed = self.layered_bytes + STEP_BYTES
        k = min(most, bytes_budget - fixed - self.overhead(1))
        while k > 0 and fixed + k + self.overhead(k) > bytes_budget:  # a count of 128 or more takes 2 bytes
            k -= 1
        return max(k, 0)

    def mapped(self, k: int, s: float | None, variant: str | None = None) -> np.ndarray:
        _, _, mapped = self.stage(k, s is not None, variant)
        return mapped if s is None else mapped + decode_detail(self.detail(k, s)).reshape(mapped.shape)


def coded_mu_grids(steps: object) -> tuple[int, ...]:
    """The grid exponents of the coded-μ candidates (:attr:`EncodeOptions.coded_mu_step`) as a tuple: an integer g
    is that grid alone, 0 none; a sequence lists them (distinct, each 1 to
    :data:`~brdfcodec.layers.coded_basis.MAX_MU_STEP_LOG2`).

    Raises
    ------
    ValueError
        Anything else, naming ``coded_mu_step``.
    """
    def one(value: object) -> int:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not (
                1 <= value <= MAX_MU_STEP_LOG2):
            raise ValueError(f"coded_mu_step must be an integer from 0 (none) to {MAX_MU_STEP_LOG2}, or a sequence "
                             f"of distinct integers from 1 to {MAX_MU_STEP_LOG2}, got {steps!r}")
        return int(value)

    if isinstance(steps, (int, np.integer)) and not isinstance(steps, bool) and steps == 0:
        return ()
    if isinstance(steps, (tuple, list)):
        grids = tuple(one(value) for value in steps)
        if len(set(grids)) != len(grids):
            one(None)  # a grid twice: refused with the same message
        return grids
    return (one(steps),)


def encode_layers(
    base: LatentRecord,
    base_mapped: npt.NDArray[np.float32],
    inputs: npt.ArrayLike,
    masks: npt.ArrayLike,
    *,
    values: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    bytes_budget: int | None = None,
    max_relae: float | None = None,
    metric: Metric = "mapped",
    step: float | None = None,
    latent_itemsize: int = 4,
    basis_fit: BasisFit | None = None,
    basis_count: int = 0,
    basis_only_fit: BasisOnlyFit | None = None,
    store_sigma: bool = True,
    basis_variants: Sequence[str] = (),
    compact_alone_fit: CompactAloneFit | None = None,
    coded_mu_steps: Sequence[int] = (),
    coded_mu_caps: Mapping[int, int] | None = None,
) -> RateResult:
    """A base record, layered to a size budget, an error target or a fixed step.

    Parameters
    ----------
    base : LatentRecord
        The base (refined μ, σ, meta).
    base_mapped : ndarray, shape (63, 90, 90)
        Decoder output of ``base.mu`` (clamped).
    inputs, masks : array_like, shape (63, 90, 90)
        The material's mapped kept slices and their validity.
    values, mask : ndarray, shape (3, 90, 90, 180), optional
        Source table (stored units) and validity; needed for ``max_relae``.
    bytes_budget : int, optional
        Largest payload in bytes.
    max_relae : float, optional
        Largest RelAE of the decoded table against ``values``.
    metric : {"mapped", "linear"}
        RelAE used by ``max_relae``.
    step : float, optional
        A fixed quantisation step instead of a target (on top of a basis layer of min(K,
        :data:`DETAIL_BASIS_COUNT`) coefficients, when there is a basis).
    latent_itemsize : int
        Bytes per stored latent value (4: float32, 2: float16).
    basis_fit : callable, optional
        Fits k coefficients on the model's shared basis (with the base's μ); None when the model has no basis.
    basis_count : int
        Size K of that basis (the most coefficients a record may carry).
    basis_only_fit : callable, optional
        Fits k coefficients of a record without a latent (format 2.1); with it, such records are candidates of a
        size budget or an error target too (not of a fixed ``step``). Needs ``basis_count``.
    store_sigma : bool, default True
        Store σ in the records (compact: one byte per dimension, or one shared byte beside a compact μ); False
        leaves it out (format 2.2) and gives its bytes to the layers.
    basis_variants : sequence of str, default ()
        Ways ``basis_fit`` can make the basis layer of a record without a detail layer (brdfcodec's writer: the
        first basis vector, ``("8", "0")``; any labels the fit understands, a coding for instance), each a
        candidate of its own: ``basis_fit`` is then called with the variant as a fourth argument. Empty:
        ``basis_fit`` takes three arguments. On a tie in error the variant listed first is kept.
    compact_alone_fit : callable, optional
        Decodes the base's μ as a compact form stores it; with it and ``store_sigma=False``, the base alone with
        μ compact and no layer (format 2.2, ``spec/bvae-format.md`` §3.2: D bytes on the fixed grid, 2 + D with a
        step) is a candidate of a size budget: the smallest record with a latent, so that every material fits
        a budget from D bytes beside its descriptor (10 for D = 8 and a one-byte name).
    coded_mu_steps : sequence of int, default ()
        For each g > 0 listed, the candidates include records whose μ is entropy-coded on the grid 2^−g in their
        coded basis layer (format 2.5, ``spec/bvae-format.md`` §4.9): a size budget's in each of
        ``basis_variants``; an error target's below the size of the smallest other record that meets it, the
        layer's bytes bisected (the smallest over the grids kept, the grid listed first on a tie); ``basis_fit``
        then receives ``"coded"`` as the μ storage and the grid as the keyword ``grid``, and must make a coded
        layer that carries μ on that grid. Empty: none.
    coded_mu_caps : mapping of int to int, optional
        For a grid g of ``coded_mu_steps``, the largest size (bytes) of its records under a size budget, where
        that is below the budget (the records a smaller budget offers, so that a larger one keeps them).

    Raises
    ------
    RateTargetError
        The budget is below the smallest record's size, or no candidate meets ``max_relae``.
    """
    if sum(x is not None for x in (bytes_budget, max_relae, step)) != 1:
        raise ValueError("give exactly one of bytes_budget, max_relae or step")
    coded_mu_steps = coded_mu_grids(tuple(coded_mu_steps))
    if metric not in ("mapped", "linear"):
        raise ValueError(f"metric must be 'mapped' or 'linear', got {metric!r}")
    full = basis_count if basis_fit is not None else 0
    target = np.asarray(inputs, dtype=np.float32)
    weights = np.asarray(masks, dtype=np.float32)
    d = base.latent_dim
    compact = bytes_budget is not None and compact_base_pays(
        bytes_budget - record_overhead(base.name, basis_count=max(full, 1)), d, latent_itemsize, full, store_sigma)
    candidates_of = functools.partial(_Candidates, store_sigma=store_sigma)
    cands = candidates_of(base, base_mapped, target, weights, latent_itemsize, basis_fit, compact)
    if cands.mu_storage == MU_INT8 and bytes_budget is not None and not _smallest_layered_fits(cands, bytes_budget):
        # μ past the fixed grid's ±3.97 with its own step does not fit beside its descriptor: the grid's end holds it
        # (spec §4.5; the coefficients are fitted to the clipped code), so every material fits the smallest budgets.
        cands = candidates_of(base, base_mapped, target, weights, latent_itemsize, basis_fit, compact,
                              fixed_grid=True)
    base_bytes = cands.plain_bytes
    if full:
        base_bytes = min(base_bytes, cands.layered_bytes + STEP_BYTES + 1 + cands.overhead(1))
    alone = None
    if compact_alone_fit is not None and not store_sigma and bytes_budget is not None:
        alone = _CompactAlone(base, compact_alone_fit, target, weights)
        base_bytes = min(base_bytes, alone.bytes_of(MU_INT8_FIXED))
    if step is not None:
        count = min(full, DETAIL_BASIS_COUNT)
        return RateResult(cands.record(count, float(step)), cands.size(count, float(step)),
                          [(float(step), cands.size(count, float(step)), None)])
    tried: list[tuple[float | None, int, float | None]] = []
    variants: tuple[str | None, ...] = tuple(basis_variants) or (None,)
    without = None
    if basis_only_fit is not None and basis_count > 0:
        without = _WithoutLatent(base, basis_only_fit, basis_count, target, weights)
    if bytes_budget is not None:
        only = None if without is None else without.for_budget(bytes_budget)
        scale = max(float((np.abs(target) * weights).sum()), np.finfo(np.float32).tiny)  # relative distortions
        if bytes_budget < base_bytes:
            if only is not None and without is not None:  # too small for a latent: the record without one
                return RateResult(without.record(only), without.size(only), tried,
                                  distortion=without.error(only) / scale)
            smallest = base_bytes if without is None else min(base_bytes, without.size(1))
            what = "base record's" if smallest == base_bytes else "smallest record's"
            raise RateTargetError(f"{base.name}: {bytes_budget} bytes is below the {what} {smallest} bytes")
        points = _budget_points(cands, bytes_budget, full, compact, variants, tried,
                                lambda: candidates_of(base, base_mapped, target, weights, latent_itemsize, basis_fit,
                                                      compact=True),
                                {} if not full else
                                {g: functools.partial(candidates_of, base, base_mapped, target, weights,
                                                      latent_itemsize, basis_fit, compact=True, coded_mu_step=g)
                                 for g in coded_mu_steps}, coded_mu_caps)
        if alone is not None and alone.storage_for(bytes_budget) is not None:
            # a candidate at every budget it fits, so that a byte more never loses what a smaller budget gave
            points.append(alone.point(bytes_budget))
        chosen = lowest_distortion(points, bytes_budget)
        pool, option = points[chosen].pool, points[chosen].option
        if only is not None and without is not None and without.error(only) < points[chosen].distortion:
            # strictly lower without a latent
            return RateResult(without.record(only), without.size(only), tried, points, without.error(only) / scale)
        return RateResult(pool.record(*option), pool.size(*option), tried, points, points[chosen].distortion / scale)
    assert max_relae is not None
    if values is None or mask is None:
        raise ValueError(f"{base.name}: max_relae needs the source table to measure the error")
    if not max_relae > 0:
        raise ValueError(f"max_relae must be > 0, got {max_relae}")
    # An error target's candidates: (compact base?, k coefficients, detail step or None).
    pools = {False: cands, True: candidates_of(base, base_mapped, target, weights, latent_itemsize, basis_fit,
                                                compact=True)}
    errors: dict[tuple[bool, int, float | None, str | None], float] = {}
    relae = RelaeAgainst(values, mask, metric)  # the source mapped and summed once for all candidates

    def error(candidate: _Candidate, variant: str | None = None) -> float:
        key = (*candidate, variant if candidate[2] is None else None)
        if key not in errors:
            compact_base, k, s, code = key
            errors[key] = relae(table_from_network_output(pools[compact_base].mapped(k, s, code))).overall
            tried.append((s, pools[compact_base].size(k, s, code), errors[key]))
        return errors[key]

    sequence = error_target_sequence(full)
    # Records without a detail layer first (in each variant), then the detail ladder: the error falls along each
    # part, but the coarsest rung (at most DETAIL_BASIS_COUNT coefficients) can be worse than all K without detail.
    plain = sum(1 for candidate in sequence if candidate[2] is None)
    meeting_variants = [variant for variant in variants if error(sequence[plain - 1], variant) <= max_relae]
    brackets = []
    for variant in meeting_variants or [None]:
        search = sequence[:plain] if meeting_variants else sequence[plain:]
        brackets.append(_bisect(lambda c, variant=variant: error(c, variant) <= max_relae, len(search), search))
    if all(bracket is None for bracket in brackets):
        only = None if without is None else without.meeting(relae, max_relae, None, tried)
        if only is not None and without is not None:
            return RateResult(without.record(only), without.size(only), tried)
        finite = [e for e in errors.values() if np.isfinite(e)]
        reached = (f"the best RelAE reached is {min(finite):.4g}" if finite else
                   "its RelAE is undefined (a near-black source: every reflectance below 1e-06 /sr)")
        raise RateTargetError(f"{base.name}: RelAE ({metric}) {max_relae} is not reachable; {reached}")
    failing, meeting = next(bracket for bracket in brackets if bracket is not None)
    if failing is not None and failing[2] is not None and meeting[2] is not None:
        # between two rungs: look for a coarser step that still meets X
        low, high = failing[2], meeting[2]
        for _ in range(_REFINE_ROUNDS - 1):
            mid_step = float(np.sqrt(low * high))
            if error((False, meeting[1], mid_step)) <= max_relae:
                high = mid_step
            else:
                low = mid_step
    # the smallest R with D <= X among every candidate measured
    candidates = [c for c in errors if errors[c] <= max_relae]
    chosen = min(candidates, key=lambda c: (pools[c[0]].size(*c[1:]), errors[c]))
    size = pools[chosen[0]].size(*chosen[1:])
    record = pools[chosen[0]].record(*chosen[1:])
    for g in coded_mu_steps if full else ():  # a smaller record whose μ rides in its coded layer (format 2.5)
        coded = candidates_of(base, base_mapped, target, weights, latent_itemsize, basis_fit, compact=True,
                              coded_mu_step=g)  # that meets X too (the grid listed first on a tie)
        k = _smallest_coded_mu_meeting(coded, size, full, relae, max_relae, tried)
        if k:
            record, size = coded.record(k, None), coded.size(k, None)
    only = None if without is None else without.meeting(relae, max_relae, size, tried)
    if only is not None and without is not None:  # a smaller record without a latent meets the target too
        return RateResult(without.record(only), without.size(only), tried)
    return RateResult(record, size, tried)


def _smallest_coded_mu_meeting(pool: _Candidates, smaller_than: int, full: int, relae: RelaeAgainst,
                               max_relae: float, tried: list[tuple[float | None, int, float | None]]) -> int:
    """The coefficients k of the smallest record of ``pool`` — μ entropy-coded in its coded layer, no detail
    layer, the basis variant after the decoder's linear path — below ``smaller_than`` bytes whose decode meets
    ``max_relae``; 0 when none does.

    The record's size is bisected (k: the most coefficients that fit it); the smallest of the records measured
    that meets the target is returned (a coded layer may take fewer bytes than its allowance, so sizes need not
    rise with k). A size at which no coded layer fits beside μ (the fit gives the base alone) does not meet it.
    Each record measured is appended to ``tried``.
    """
    measured: dict[int, tuple[int, float] | None] = {}  # k → (bytes, RelAE); None: no coded layer at k

    def meeting(k: int) -> bool:
        found = measured.get(k)
        return found is not None and found[0] < smaller_than and found[1] <= max_relae

    def meets(budget: int) -> bool:
        k = pool.most_coefficients(budget, full)
        if not k:
            return False
        if k not in measured:
            measured[k] = None
            if isinstance(pool.record(k, None), LayeredRecord):  # else the base alone: μ not coded
                size = pool.size(k, None)
                error = relae(table_from_network_output(pool.mapped(k, None))).overall
                tried.append((None, size, error))
                measured[k] = (size, error)
        return meeting(k)

    low = pool.layered_bytes + STEP_BYTES + pool.overhead(1)  # no coefficient fits: never meets
    high = smaller_than - 1
    if high <= low or not meets(high):
        return 0
    while high - low > 1:  # meets(high); not meets(low)
        middle = (low + high) // 2
        if meets(middle):
            high = middle
        else:
            low = middle
    return min((found[0], k) for k, found in measured.items() if found is not None and meeting(k))[1]


def _budget_points(cands: _Candidates, bytes_budget: int, full: int, compact: bool,
                   variants: tuple[str | None, ...], tried: list[tuple[float | None, int, float | None]],
                   compact_pool: Callable[[], _Candidates],
                   coded_pools: Mapping[int, Callable[[], _Candidates]] | None = None,
                   coded_caps: Mapping[int, int] | None = None) -> list[RatePoint]:
    """Every candidate record of a size budget that fits it, with its rate and kept-slice distortion.

    The candidates, each the largest of its kind that fits (within a kind, more bytes lower the error): the base
    alone; the most basis coefficients that fit, in each of ``variants``, on the base ``cands`` stores (compact or
    not, :func:`compact_base_pays`) and, where that base is the full one, on a compact base too (so that a byte
    more never loses what the compact base gave, issue 39); and min(k, n) int8 coefficients, for each n of
    :data:`DETAIL_BASIS_COUNTS`, under a detail layer at each step of the ladder search that fits (where a detail
    layer has room); and, for each grid g of ``coded_pools`` (its pool's factory), the most coefficients that fit
    beside a μ entropy-coded on the grid 2^−g in their layer (format 2.5), in each of ``variants``, within
    ``coded_caps[g]`` bytes where that is given and below the budget.
    """
    pools: dict[bool | str, _Candidates] = {compact: cands}
    options: list[tuple[bool | str, int, float | None, str | None]] = [(compact, 0, None, None)]
    k = cands.most_coefficients(bytes_budget, full)
    if k:
        options += [(compact, k, None, variant) for variant in variants]
    if full and not compact:
        pools[True] = compact_pool()
        most = pools[True].most_coefficients(bytes_budget, full)
        if most:
            options += [(True, most, None, variant) for variant in variants]
    for g, coded_pool in (coded_pools or {}).items():
        key = f"{MU_CODED}-{g}"
        pools[key] = coded_pool()
        most = pools[key].most_coefficients(min(bytes_budget, (coded_caps or {}).get(g, bytes_budget)), full)
        if most:
            options += [(key, most, None, variant) for variant in variants]
    # A detail layer only where it fits beside its coefficients (no room at 64 B: 48 coefficients, no detail).
    empty = _empty_detail_bytes()
    for under_detail in sorted({min(k, count) for count in DETAIL_BASIS_COUNTS}):
        smallest_detail = (cands.layered_bytes + (STEP_BYTES + under_detail if under_detail else 0) + empty
                           + cands.overhead(under_detail or None, empty))
        if smallest_detail <= bytes_budget:
            options += [(compact, under_detail, s, None)
                        for s in _finest_fitting_steps(cands, under_detail, bytes_budget, tried)]
    points = []
    seen: set[int] = set()  # a variant the fit declines gives the same layer as another: one point
    for c, n, s, coding in dict.fromkeys(options):
        pool = pools[c]
        size = pool.size(n, s, coding)
        layer = pool.stage(n, s is not None, coding)[1]
        if layer is not None and s is None and id(layer) in seen:
            continue
        seen.add(id(layer))
        if size <= bytes_budget:
            mapped = np.clip(pool.mapped(n, s, coding), 0.0, MAPPED_MAX)
            points.append(RatePoint(size, float((np.abs(mapped - pool.inputs) * pool.masks).sum()), c is not False,
                                    (n, s, coding), pool))
    return points


def lowest_distortion(points: Sequence[RatePoint], bytes_budget: int) -> int:
    """Index of the point of lowest distortion D among those of rate R ≤ ``bytes_budget``: the solution of
    min D + λR over the candidates for the λ that the budget calls for.

    The Lagrangian sweep (:func:`lagrangian_hull`) reaches only the lower convex hull of the (R, D) points; the
    best hull point that fits is never better than the best fitting point, which is what this returns (so a
    point inside the hull that fits the budget better is not lost). Ties: fewer basis coefficients, then the full
    base, then the variant listed first.

    Raises
    ------
    ValueError
        No point fits the budget.
    """
    fitting = [i for i, p in enumerate(points) if p.rate <= bytes_budget]
    if not fitting:
        raise ValueError(f"no candidate fits {bytes_budget} bytes")
    return min(fitting, key=lambda i: (points[i].distortion, points[i].option[0], points[i].compact, i))


def lagrangian_hull(points: Sequence[tuple[float, float]]) -> list[tuple[int, float, float]]:
    """The points a sweep of λ over min D + λR reaches: the lower convex hull of (R, D), by rising R.

    Parameters
    ----------
    points : sequence of (rate, distortion)

    Returns
    -------
    list of (index, λ low, λ high)
        Each hull point's index in ``points`` and the range of λ (distortion per byte, ≥ 0) for which it
        minimises D + λR: λ high of a point is λ low of the next smaller one; the largest point's λ low is 0
        and the smallest's λ high infinite.
    """
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    hull: list[int] = []
    for i in order:
        r, d = points[i]
        if hull and d >= points[hull[-1]][1]:
            continue  # no lower than a smaller point: never optimal for λ ≥ 0
        while len(hull) >= 2:
            (r1, d1), (r2, d2) = points[hull[-2]], points[hull[-1]]
            if (d2 - d1) * (r - r1) >= (d - d1) * (r2 - r1):  # the middle point lies on or above the chord
                hull.pop()
            else:
                break
        hull.append(i)
    out = []
    for j, i in enumerate(hull):
        high = np.inf if j == 0 else (points[hull[j - 1]][1] - points[i][1]) / (points[i][0] - points[hull[j - 1]][0])
        low = 0.0 if j == len(hull) - 1 else (points[i][1] - points[hull[j + 1]][1]) / (
            points[hull[j + 1]][0] - points[i][0])
        out.append((i, float(low), float(high)))
    return out


class _WithoutLatent:
    """Candidates without a latent (format 2.1): k coefficients from the basis' first vector on the linear-path
    mean, fitted once per k."""

    def __init__(self, base: LatentRecord, fit: BasisOnlyFit, basis_count: int, inputs: np.ndarray,
                 masks: np.ndarray) -> None:
        self.base, self.fit, self.basis_count = base, fit, basis_count
        self.inputs, self.masks = inputs, masks
        self.fits: dict[int, tuple[BasisLayer, np.ndarray]] = {}

    def layer(self, k: int) -> tuple[BasisLayer, np.ndarray]:
        if k not in self.fits:
            self.fits[k] = self.fit(k)
        return self.fits[k]

    def size(self, k: int) -> int:
        """Payload and descriptor of the record fitted in the bytes of k int8 coefficients (the step and k bytes;
        a packed layer's own size once fitted, which is at most that)."""
        if k in self.fits:
            layer = self.fits[k][0]
            return layer.nbytes + record_overhead(self.base.name, basis_count=layer.count,
                                                  basis_bytes=_coded_bytes(layer))
        return STEP_BYTES + k + record_overhead(self.base.name, basis_count=k)

    def for_budget(self, bytes_budget: int) -> int | None:
        """The most coefficients (at most K) whose record fits the budget; None when not even one does."""
        k = min(self.basis_count, bytes_budget - STEP_BYTES - record_overhead(self.base.name, basis_count=1))
        while k > 0 and self.size(k) > bytes_budget:  # a count of 128 or more takes 2 bytes
            k -= 1
        return k if k > 0 else None

    def error(self, k: int) -> float:
        """The kept-slice mapped L1 error of the clamped decode (what a size budget ranks candidates by)."""
        mapped = np.clip(self.layer(k)[1], 0.0, MAPPED_MAX)
        return float((np.abs(mapped - self.inputs) * self.masks).sum())

    def record(self, k: int) -> LayeredRecord:
        return LayeredRecord.without_latent(self.base.name, self.base.latent_dim, self.layer(k)[0],
                                            meta=self.base.meta)

    def meeting(self, relae: RelaeAgainst, max_relae: float, smaller_than: int | None,
                tried: list[tuple[float | None, int, float | None]]) -> int | None:
        """The fewest coefficients, of the error target's counts for a compact base (those whose record is
        smaller than ``smaller_than`` bytes, when given), whose decode meets ``max_relae``; None when none does."""
        counts = [c[1] for c in error_target_sequence(self.basis_count) if c[0] and c[2] is None]
        counts = [n for n in counts if smaller_than is None or self.size(n) < smaller_than]
        if not counts:
            return None
        measured: dict[int, float] = {}

        def meets(candidate: _Candidate) -> bool:
            k = candidate[1]
            if k not in measured:
                measured[k] = relae(table_from_network_output(self.layer(k)[1])).overall
                tried.append((None, self.size(k), measured[k]))
            return measured[k] <= max_relae

        bracket = _bisect(meets, len(counts), [(True, n, None) for n in counts])
        return None if bracket is None else bracket[1][1]


class _CompactAlone:
    """The base alone with μ stored compact, without σ and without a layer (format 2.2, ``spec/bvae-format.md``
    §3.2): the smallest record with a latent. μ is stored as the compact base of a layered record would store it
    (:func:`compact_mu_storage`), or on the fixed grid, its values past ±3.97 at the grid's end, where the budget
    is too small for the step (spec §4.5)."""

    def __init__(self, base: LatentRecord, fit: CompactAloneFit, inputs: np.ndarray, masks: np.ndarray) -> None:
        self.base, self.fit, self.inputs, self.masks = base, fit, inputs, masks
        self.fits: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def bytes_of(self, storage: str) -> int:
        """Payload and descriptor: D bytes (2 + D with a step) and the descriptor of a record without layers."""
        return _layered_base_bytes(self.base.latent_dim, 0, storage, store_sigma=False) + record_overhead(
            self.base.name)

    def size(self, k: int, s: float | None, storage: str) -> int:
        """The size of a :meth:`point`'s option (``k`` 0, ``s`` None: no layer)."""
        return self.bytes_of(storage)

    def storage_for(self, bytes_budget: int) -> str | None:
        """How μ is stored within the budget: as a compact base stores it, else on the fixed grid; None when even
        that does not fit."""
        for storage in dict.fromkeys((compact_mu_storage(self.base.mu), MU_INT8_FIXED)):
            if self.bytes_of(storage) <= bytes_budget:
                return storage
        return None

    def _fitted(self, storage: str) -> tuple[np.ndarray, np.ndarray]:
        if storage not in self.fits:
            self.fits[storage] = self.fit(storage)
        return self.fits[storage]

    def point(self, bytes_budget: int) -> RatePoint:
        """The record within the budget as a rate point (its kept-slice mapped L1 error, clamped decode)."""
        storage = self.storage_for(bytes_budget)
        assert storage is not None
        mapped = np.clip(self._fitted(storage)[1], 0.0, MAPPED_MAX)
        return RatePoint(self.bytes_of(storage), float((np.abs(mapped - self.inputs) * self.masks).sum()), True,
                         (0, None, storage), self)

    def record(self, k: int, s: float | None, storage: str) -> LayeredRecord:
        """The record of a :meth:`point`'s option (``k`` 0, ``s`` None: no layer)."""
        code = self._fitted(storage)[0]
        return LayeredRecord(self.base.name, code, self.base.sigma, self.base.meta, compact_mu=True,
                             fixed_mu_grid=storage == MU_INT8_FIXED, store_sigma=False)


def _coded_bytes(layer: BasisLayer | None) -> int | None:
    """An entropy-coded basis layer's bytes (its descriptor states them, format 2.4); None for any other."""
    return layer.nbytes if layer is not None and layer.prior is not None else None


def error_target_sequence(basis_count: int) -> list[_Candidate]:
    """The candidates an error target tries, smallest first: ``(compact base, k coefficients, detail step)``.

    With a shared basis of K vectors: 4, 8, 16 and 32 coefficients (those below K), then all K, on a compact
    base (the same rule as a size budget: a record too small for all K coefficients beside μ in the latent
    dtype stores its base compact), then min(K, :data:`DETAIL_BASIS_COUNT`) coefficients on the latent-dtype
    base under each rung of :data:`STEP_LADDER`, coarse to fine. Without a basis: the base alone, then the base
    under each rung.
    The base alone is not tried where there is a basis: four coefficients on a compact base are smaller
    (17 bytes for D = 8 against 24 or 40) and, fitted from no coefficients up, no worse on the material
    beyond the int8 rounding of μ.
    """
    if basis_count <= 0:
        return [(False, 0, None), *((False, 0, s) for s in STEP_LADDER)]
    counts = [n for n in _BASIS_COUNTS if n < basis_count] + [basis_count]
    under_detail = min(basis_count, DETAIL_BASIS_COUNT)
    return [*((True, n, None) for n in counts), *((False, under_detail, s) for s in STEP_LADDER)]


def compact_base_pays(bytes_budget: int, latent_dim: int, latent_itemsize: int, basis_count: int,
                      store_sigma: bool = True) -> bool:
    """Whether a size budget stores the base compact: when it cannot hold all K basis coefficients beside μ in
    the latent dtype (and σ as one byte each).

    A compact base (μ as int8 on the fixed grid or with a float16 step, one shared σ byte: 9 or 11 bytes for
    D = 8 instead of 24 in float16 or 40 in float32) frees 13 to 31 bytes for coefficients, at a cost in error
    that is small beside what those coefficients gain (documentation: Layers and rate control).
    Above that, the bytes would go to the detail layer, where they buy little.
    """
    full_base = _layered_base_bytes(latent_dim, latent_itemsize, None, store_sigma)
    return basis_count > 0 and bytes_budget < full_base + STEP_BYTES + basis_count


def compact_mu_storage(mu: npt.ArrayLike) -> str:
    """How a compact base stores μ: on the fixed grid (D bytes) where every value is within its ±3.97, else
    with its own float16 step (2 + D bytes).

    The 2 bytes saved go to basis coefficients: on materials the model was not trained on, that lowers the
    error at the smallest budgets, while at larger ones the coarser μ costs about as much as the 2 more
    coefficients gain (documentation: Layers and rate control).
    """
    return MU_INT8_FIXED if fits_fixed_mu_grid(mu) else MU_INT8


def _smallest_layered_fits(cands: _Candidates, bytes_budget: int) -> bool:
    """Whether the candidates' smallest layered record (their base, the step, one coefficient and the record's
    descriptor) fits the budget."""
    return cands.layered_bytes + STEP_BYTES + 1 + cands.overhead(1) <= bytes_budget


def _layered_base_bytes(latent_dim: int, latent_itemsize: int, mu_storage: MuStorage, store_sigma: bool = True) -> int:
    """Payload of a layered record's base: μ in the latent dtype and σ as one byte per dimension, or (compact) μ
    as D int8 values (after a float16 step unless on the fixed grid) and σ as one shared byte; no σ bytes when σ
    is not stored (format 2.2)."""
    if mu_storage is None:
        return latent_dim * latent_itemsize + (latent_dim if store_sigma else 0)
    if mu_storage == MU_CODED:  # μ's bytes are the coded layer's (format 2.5)
        return 1 if store_sigma else 0
    return latent_dim + (1 if store_sigma else 0) + (STEP_BYTES if mu_storage == MU_INT8 else 0)


@functools.cache
def _empty_detail_bytes() -> int:
    """Payload of the smallest detail layer (all coefficients zero, coarsest step)."""
    return encode_detail(np.zeros(NETWORK_INPUT_SHAPE, dtype=np.float32), STEP_LADDER[0]).nbytes


def _finest_fitting_steps(cands: _Candidates, k: int, bytes_budget: int,
                          tried: list[tuple[float | None, int, float | None]]) -> list[float]:
    """Detail steps over k basis coefficients that fit ``bytes_budget``, found on the way to the finest one.

    Bisects :data:`STEP_LADDER` (sizes grow as the step falls), then a few log-space halvings between the two
    rungs that bracket the budget; appends every size it measured to ``tried``.
    """
    ladder: list[float | None] = [None, *STEP_LADDER]
    lo, hi = 0, len(ladder)  # ladder[lo] fits (no detail fits); ladder[hi] does not (or is past the end)
    start = len(tried)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        tried.append((ladder[mid], cands.size(k, ladder[mid]), None))
        if cands.size(k, ladder[mid]) <= bytes_budget:
            lo = mid
        else:
            hi = mid
    if lo > 0 and hi < len(ladder):  # between two rungs: a few halvings of the step ratio, in log space
        fine, coarse = ladder[hi], ladder[lo]
        for _ in range(_REFINE_ROUNDS):
            mid_step = float(np.sqrt(fine * coarse))  # type: ignore[operator]
            tried.append((mid_step, cands.size(k, mid_step), None))
            if cands.size(k, mid_step) <= bytes_budget:
                coarse = mid_step
            else:
                fine = mid_step
    return [s for s, n, _ in tried[start:] if s is not None and n <= bytes_budget]


def _bisect(
    ok: Callable[[_Candidate], bool], n: int, sequence: list[_Candidate]
) -> tuple[_Candidate | None, _Candidate] | None:
    """Bracket the first candidate of ``sequence`` (ordered from smallest to largest) for which ``ok`` holds.

    Returns ``(last failing, first passing)`` — ``(None, first)`` when the first passes — or None when even the
    last fails. ``ok`` is assumed to hold from some candidate on.
    """
    if ok(sequence[0]):
        return None, sequence[0]
    lo, hi = 0, n - 1  # ok(lo) false
    if not ok(sequence[hi]):
        return None
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if ok(sequence[mid]):
            hi = mid
        else:
            lo = mid
    return sequence[lo], sequence[hi]


def smallest_bytes_budget(
    latent_dim: int, latent_itemsize: int, basis: bool, *, without_latent: bool = False, store_sigma: bool = True
) -> int:
    """The smallest ``bytes_budget`` that any material can be encoded within, for a model's latent size.

    The smallest record is a compact base (μ on the fixed grid, one σ byte) with one basis coefficient, or, without
    a basis layer, a latent record (μ and σ in the latent dtype); in records without σ (format 2.2), the base
    alone with μ on the fixed grid (D bytes; a μ past the grid's ±3.97 is stored at its end); each with the
    descriptor of a one-byte name. Where records without a latent may be written (format 2.1), one basis
    coefficient alone: 6 bytes. A material whose name is longer needs a little more: :func:`encode_layers`
    refuses it then. Checked before any model is loaded (``bvae compress --bytes``).

    Parameters
    ----------
    latent_dim : int
        D.
    latent_itemsize : int
        Bytes of one value in the latent dtype (4 or 2).
    basis : bool
        Whether records may hold a basis layer (the model has a shared basis and it is not turned off).
    without_latent : bool, default False
        Whether records without a latent may be written (``EncodeOptions.latent = "auto"``, a shared basis and a
        decoder whose linear path covers it).
    store_sigma : bool, default True
        Whether records store σ (False: format 2.2, μ alone).

    Returns
    -------
    int
    """
    plain = (2 if store_sigma else 1) * latent_dim * latent_itemsize + record_overhead("a")
    if not store_sigma:  # the base alone, μ compact on the fixed grid, no layer (format 2.2)
        alone = _layered_base_bytes(latent_dim, latent_itemsize, MU_INT8_FIXED, store_sigma=False)
        plain = min(plain, alone + record_overhead("a"))
    if not basis:
        return plain
    if without_latent:
        return STEP_BYTES + 1 + record_overhead("a", basis_count=1)
    compact = _layered_base_bytes(latent_dim, latent_itemsize, MU_INT8_FIXED, store_sigma) + STEP_BYTES + 1
    return min(plain, compact + record_overhead("a", basis_count=1))
