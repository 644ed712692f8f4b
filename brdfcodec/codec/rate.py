"""Layered encoding with rate control: a size budget or an error target per material.

Given a material's base code, its decode and its source, :func:`encode_layers`
chooses the enhancement layers: k coefficients on the model's shared basis
(:mod:`brdfcodec.layers.basis`, when the model has one) and a detail layer
whose quantisation step comes from a fixed ladder (:data:`STEP_LADDER`,
halving every two rungs):

- ``bytes_budget=N``: as many coefficients as fit (up to the basis' size
  K) without a detail layer, and at most :data:`DETAIL_BASIS_COUNT` under
  one, with the finest rung whose record payload (μ, σ and the layers) fits
  in N bytes; of those records, the base alone and (past the budgets that
  store the base compact) the compact base with all K coefficients, the one
  with the lowest kept-slice mapped L1 error (fewer coefficients on a tie).
  No error is traded for decode time, so that a larger budget never returns
  a worse record than a smaller one (the base alone stays a candidate of
  every budget that holds it, the compact base's best of the budgets past
  the compact ones unless a detail layer wins by far; more coefficients fit
  no worse than fewer:
  ``tests/test_rate_monotone.py``). The cap bounds
  every layered record's
  decode time; where a detail layer has room, the bytes of coefficients past
  the first few dozen buy more as detail anyway
  (documentation: Layers and rate control);
- ``max_relae=X``: the first of 4, 8, 16, 32 and K basis coefficients on a
  compact base, then (if K misses X) min(K, :data:`DETAIL_BASIS_COUNT`)
  coefficients plus each rung from coarse to fine, whose decoded table has
  a measured RelAE (mapped or linear, full table, valid entries) of at most
  X — the smallest file that meets X (:func:`error_target_sequence`).

Both searches bisect (size falls and error rises along the sequence), then
bisect the step in log space between the two rungs that bracket the target
(3 rounds for a budget, 2 for an error target), and return the best of every
candidate actually tried, so the answer is the smallest tried file that
meets the target even where the curve is not monotonic. The achieved RelAE
is measured on the returned record. A layered record stores σ compactly
(one byte per dimension, ``spec/bvae-format.md`` §4.5); under a budget too
small for all K coefficients beside μ in the latent dtype (and for an error
target, in every record without a detail layer), the base itself is
compact (μ as int8 on the fixed grid μ = q / 32 where it fits ±3.97, else
with a float16 step; σ as one shared byte: 9 or 11 bytes for D = 8,
:func:`compact_base_pays`, :func:`compact_mu_storage`), which makes budgets
from 12 bytes possible.

Records without a latent (format 2.1, ``spec/bvae-format.md`` §4.6) are candidates too when a
:data:`BasisOnlyFit` is given (``EncodeOptions.latent = "auto"``): k coefficients from the basis' first vector
on the decoder's linear-path mean, as many as fit the budget beside the step and the descriptor (for an error
target, the same counts as the compact base's). Rate control compares them with the latent candidates as it
compares those: the lower kept-slice mapped L1 error for a budget (the latent record on a tie, since it can be
edited), the smaller record meeting an error target. Budgets too small for any record with a latent (from
6 bytes with a one-byte name) then hold one without.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import MAPPED_MAX, NETWORK_INPUT_SHAPE
from brdfcodec.errors import RateTargetError
from brdfcodec.format.bvae import LatentRecord, record_overhead
from brdfcodec.format.layered_record import MU_INT8, MU_INT8_FIXED, LayeredRecord
from brdfcodec.layers.basis import STEP_BYTES, BasisLayer, fits_fixed_mu_grid
from brdfcodec.layers.detail import DetailLayer, decode_detail, encode_detail
from brdfcodec.representation.metrics import RelaeAgainst
from brdfcodec.representation.network_io import table_from_network_output

__all__ = [
    "DETAIL_BASIS_COUNT", "STEP_LADDER", "BasisFit", "BasisOnlyFit", "Metric", "MuStorage", "RateResult",
    "compact_base_pays", "compact_mu_storage",
    "encode_layers",
    "error_target_sequence", "layered_mapped",
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
    """

    record: LatentRecord
    payload_bytes: int
    tried: list[tuple[float | None, int, float | None]]


#: How a record stores μ: None in the file's latent dtype, else compact (``layers.mu``): ``"int8"`` (a float16
#: step and D int8 values) or ``"int8-fixed"`` (D int8 values on the fixed grid μ = q / 32).
MuStorage = str | None
#: What a basis fit returns for k coefficients, how μ is stored (when compact, the code it returns is the
#: quantised one, and the coefficients are fitted to it) and whether a detail layer will follow (the writer may
#: then choose differently, for decode time: :func:`~brdfcodec.codec.encoding.layer_records`): the base with its
#: jointly refined μ, the layer, and the decoder's mapped output before the detail layer (clamped base decode
#: plus the basis residual).
BasisFit = Callable[[int, MuStorage, bool], tuple[LatentRecord, BasisLayer, np.ndarray]]
#: What a fit of a record without a latent (format 2.1) returns for k coefficients on the basis' vectors
#: 0 … k − 1: the layer (quantised as stored) and the decode's mapped kept slices before the clamp (the decoder's
#: linear-path mean at the basis' entries plus the layer's sum).
BasisOnlyFit = Callable[[int], tuple[BasisLayer, np.ndarray]]
#: Basis sizes tried by an error target below the basis' full size.
_BASIS_COUNTS: Final = (4, 8, 16, 32)
#: A candidate of an error target: compact base or not, basis coefficients, detail step (None: no detail layer).
_Candidate = tuple[bool, int, float | None]
#: How much lower than all K coefficients on the full base another candidate's kept-slice error must be for a size
#: budget to skip the compact base's best (how the two store μ moves the error by a fraction of that).
_COMPACT_MARGIN: Final = 0.02
#: The most basis coefficients a record with a detail layer carries, so that decoding any layered record stays
#: within 1.5 times its base-only decode (the basis sum reads every factor its coefficients use: the leading
#: coefficients use fewer of them than all K do). Where a detail layer has room, the bytes of further coefficients
#: buy more as detail, so the cap costs little error against also trying all K (documentation: Layers and rate
#: control).
DETAIL_BASIS_COUNT: Final = 32


def layered_mapped(base_mapped: np.ndarray, record: LatentRecord) -> np.ndarray:
    """Base decode plus the record's detail layer, if any (mapped, network layout)."""
    if isinstance(record, LayeredRecord) and record.detail is not None:
        return base_mapped + decode_detail(record.detail).reshape(base_mapped.shape)
    return base_mapped


class _Candidates:
    """Records made of the base, k basis coefficients (0: none) and a detail layer at step s (None: none)."""

    def __init__(self, base: LatentRecord, base_mapped: np.ndarray, inputs: np.ndarray, masks: np.ndarray,
                 latent_itemsize: int, basis_fit: BasisFit | None, compact: bool = False,
                 fixed_grid: bool = False, store_sigma: bool = True) -> None:
        self.base, self.inputs, self.masks = base, inputs, masks
        self.store_sigma = store_sigma
        d = base.latent_dim
        # the base alone: μ (and σ, when stored) in the latent dtype, and its descriptor
        self.plain_bytes = (2 if store_sigma else 1) * d * latent_itemsize + record_overhead(base.name)
        self.mu_storage = (MU_INT8_FIXED if fixed_grid else compact_mu_storage(base.mu)) if compact else None
        self.layered_bytes = _layered_base_bytes(d, latent_itemsize, self.mu_storage, store_sigma)
        self.basis_fit = basis_fit
        self.stages: dict[tuple[int, bool], tuple[LatentRecord, BasisLayer | None, np.ndarray]] = {
            (0, False): (base, None, base_mapped), (0, True): (base, None, base_mapped)}
        self.details: dict[tuple[int, float], DetailLayer] = {}

    def stage(self, k: int, under_detail: bool = False) -> tuple[LatentRecord, BasisLayer | None, np.ndarray]:
        """Base and k basis coefficients, for a record without a detail layer or (``under_detail``) with one."""
        if (k, under_detail) not in self.stages:
            assert self.basis_fit is not None and k > 0
            self.stages[k, under_detail] = self.basis_fit(k, self.mu_storage, under_detail)
        return self.stages[k, under_detail]

    def detail(self, k: int, s: float) -> DetailLayer:
        if (k, s) not in self.details:
            _, _, mapped = self.stage(k, True)
            self.details[k, s] = encode_detail((self.inputs - mapped) * self.masks, s)
        return self.details[k, s]

    def record(self, k: int, s: float | None) -> LatentRecord:
        base, basis, _ = self.stage(k, s is not None)
        if basis is None and s is None:
            return base
        detail = None if s is None else self.detail(k, s)
        storage: dict[str, bool] = {"compact_sigma": True} if self.store_sigma else {"store_sigma": False}
        if self.mu_storage is not None:
            storage = {"compact_mu": True, "fixed_mu_grid": self.mu_storage == MU_INT8_FIXED,
                       **({"shared_sigma": True} if self.store_sigma else {"store_sigma": False})}
        return LayeredRecord(base.name, base.mu, base.sigma, base.meta, detail=detail, basis=basis, **storage)

    def size(self, k: int, s: float | None) -> int:
        _, basis, _ = self.stage(k, s is not None)
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

    def mapped(self, k: int, s: float | None) -> np.ndarray:
        _, _, mapped = self.stage(k, s is not None)
        return mapped if s is None else mapped + decode_detail(self.detail(k, s)).reshape(mapped.shape)


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

    Raises
    ------
    RateTargetError
        The budget is below the smallest record's size, or no candidate meets ``max_relae``.
    """
    if sum(x is not None for x in (bytes_budget, max_relae, step)) != 1:
        raise ValueError("give exactly one of bytes_budget, max_relae or step")
    if metric not in ("mapped", "linear"):
        raise ValueError(f"metric must be 'mapped' or 'linear', got {metric!r}")
    full = basis_count if basis_fit is not None else 0
    target = np.asarray(inputs, dtype=np.float32)
    weights = np.asarray(masks, dtype=np.float32)
    d = base.latent_dim
    compact = bytes_budget is not None and compact_base_pays(
        bytes_budget - record_overhead(base.name, basis_count=max(full, 1)), d, latent_itemsize, full, store_sigma)
    candidates = functools.partial(_Candidates, store_sigma=store_sigma)
    cands = candidates(base, base_mapped, target, weights, latent_itemsize, basis_fit, compact)
    if cands.mu_storage == MU_INT8 and bytes_budget is not None and not _smallest_layered_fits(cands, bytes_budget):
        # μ past the fixed grid's ±3.97 with its own step does not fit beside its descriptor: the grid's end holds it
        # (spec §4.5; the coefficients are fitted to the clipped code), so every material fits the smallest budgets.
        cands = candidates(base, base_mapped, target, weights, latent_itemsize, basis_fit, compact, fixed_grid=True)
    base_bytes = cands.plain_bytes
    if full:
        base_bytes = min(base_bytes, cands.layered_bytes + STEP_BYTES + 1 + cands.overhead(1))
    if step is not None:
        count = min(full, DETAIL_BASIS_COUNT)
        return RateResult(cands.record(count, float(step)), cands.size(count, float(step)),
                          [(float(step), cands.size(count, float(step)), None)])
    tried: list[tuple[float | None, int, float | None]] = []
    without = None
    if basis_only_fit is not None and basis_count > 0:
        without = _WithoutLatent(base, basis_only_fit, basis_count, target, weights)
    if bytes_budget is not None:
        only = None if without is None else without.for_budget(bytes_budget)
        if bytes_budget < base_bytes:
            if only is not None and without is not None:  # too small for a latent: the record without one
                return RateResult(without.record(only), without.size(only), tried)
            smallest = base_bytes if without is None else min(base_bytes, without.size(1))
            what = "base record's" if smallest == base_bytes else "smallest record's"
            raise RateTargetError(f"{base.name}: {bytes_budget} bytes is below the {what} {smallest} bytes")
        k = cands.most_coefficients(bytes_budget, full)
        under_detail = min(k, DETAIL_BASIS_COUNT)
        fitting: set[tuple[int, float | None]] = {c for c in ((0, None), (k, None)) if cands.size(*c) <= bytes_budget}
        # A detail layer only where it fits beside its coefficients (no room at 64 B: 48 coefficients, no detail).
        empty = _empty_detail_bytes()
        smallest_detail = (cands.layered_bytes + (STEP_BYTES + under_detail if under_detail else 0) + empty
                           + cands.overhead(under_detail or None, empty))
        if smallest_detail <= bytes_budget:
            fitting |= {(under_detail, s) for s in _finest_fitting_steps(cands, under_detail, bytes_budget, tried)}

        pools = {compact: cands}
        options = {(compact, *c) for c in fitting}

        # Among the candidates, the lowest kept-slice L1 error (a very coarse layer can be worse than none), fewer
        # coefficients on a tie. No error is traded for decode time: a budget whose smaller neighbours cannot hold
        # the base alone would otherwise return the base alone, worse than what they return (issue 39).
        def slice_error(candidate: _Candidate) -> float:
            mapped = np.clip(pools[candidate[0]].mapped(*candidate[1:]), 0.0, MAPPED_MAX)
            return float((np.abs(mapped - target) * weights).sum())

        errors = {c: slice_error(c) for c in options}
        # Past the budgets that store the base compact, their best record (the compact base with all K coefficients)
        # stays a candidate wherever nothing beats all K on the full base by more than what μ's storage can change
        # (_COMPACT_MARGIN), so that one byte more never loses what the compact base gave (a refit of the
        # coefficients to the compact μ; a large budget, whose detail layer wins by far, does not pay it).
        full_plain = (False, full, None)
        if full and not compact and full_plain in errors and (
                min(errors.values()) > (1 - _COMPACT_MARGIN) * errors[full_plain]):
            pools[True] = candidates(base, base_mapped, target, weights, latent_itemsize, basis_fit, compact=True)
            if pools[True].size(full, None) <= bytes_budget:
                errors[True, full, None] = slice_error((True, full, None))
        chosen = min(errors, key=lambda c: (errors[c], c[1], c[0]))
        if only is not None and without is not None and without.error(only) < errors[chosen]:
            return RateResult(without.record(only), without.size(only), tried)  # strictly lower: a latent on a tie
        return RateResult(pools[chosen[0]].record(*chosen[1:]), pools[chosen[0]].size(*chosen[1:]), tried)
    assert max_relae is not None
    if values is None or mask is None:
        raise ValueError(f"{base.name}: max_relae needs the source table to measure the error")
    if not max_relae > 0:
        raise ValueError(f"max_relae must be > 0, got {max_relae}")
    # An error target's candidates: (compact base?, k coefficients, detail step or None).
    pools = {False: cands, True: candidates(base, base_mapped, target, weights, latent_itemsize, basis_fit,
                                             compact=True)}
    errors: dict[_Candidate, float] = {}
    relae = RelaeAgainst(values, mask, metric)  # the source mapped and summed once for all candidates

    def error(candidate: _Candidate) -> float:
        if candidate not in errors:
            compact_base, k, s = candidate
            errors[candidate] = relae(table_from_network_output(pools[compact_base].mapped(k, s))).overall
            tried.append((s, pools[compact_base].size(k, s), errors[candidate]))
        return errors[candidate]

    sequence = error_target_sequence(full)
    # Records without a detail layer first, then the detail ladder: the error falls along each part, but the
    # coarsest rung (at most DETAIL_BASIS_COUNT coefficients) can be worse than all K without detail.
    plain = sum(1 for candidate in sequence if candidate[2] is None)
    search = sequence[:plain] if error(sequence[plain - 1]) <= max_relae else sequence[plain:]
    bracket = _bisect(lambda c: error(c) <= max_relae, len(search), search)
    if bracket is None:
        only = None if without is None else without.meeting(relae, max_relae, None, tried)
        if only is not None and without is not None:
            return RateResult(without.record(only), without.size(only), tried)
        finite = [e for e in errors.values() if np.isfinite(e)]
        reached = (f"the best RelAE reached is {min(finite):.4g}" if finite else
                   "its RelAE is undefined (a near-black source: every reflectance below 1e-06 /sr)")
        raise RateTargetError(f"{base.name}: RelAE ({metric}) {max_relae} is not reachable; {reached}")
    failing, meeting = bracket
    if failing is not None and failing[2] is not None and meeting[2] is not None:
        # between two rungs: look for a coarser step that still meets X
        low, high = failing[2], meeting[2]
        for _ in range(_REFINE_ROUNDS - 1):
            mid_step = float(np.sqrt(low * high))
            if error((False, meeting[1], mid_step)) <= max_relae:
                high = mid_step
            else:
                low = mid_step
    candidates = [c for c in errors if errors[c] <= max_relae]
    chosen = min(candidates, key=lambda c: pools[c[0]].size(*c[1:]))
    size = pools[chosen[0]].size(*chosen[1:])
    only = None if without is None else without.meeting(relae, max_relae, size, tried)
    if only is not None and without is not None:  # a smaller record without a latent meets the target too
        return RateResult(without.record(only), without.size(only), tried)
    return RateResult(pools[chosen[0]].record(*chosen[1:]), size, tried)


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
    a basis layer, a latent record (μ and σ in the latent dtype); each with the descriptor of a one-byte name. Where
    records without a latent may be written (format 2.1), one basis coefficient alone: 6 bytes. A
    material whose μ leaves the fixed grid, or whose name is longer, needs a little more: :func:`encode_layers`
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
    if not basis:
        return plain
    if without_latent:
        return STEP_BYTES + 1 + record_overhead("a", basis_count=1)
    compact = _layered_base_bytes(latent_dim, latent_itemsize, MU_INT8_FIXED, store_sigma) + STEP_BYTES + 1
    return min(plain, compact + record_overhead("a", basis_count=1))
