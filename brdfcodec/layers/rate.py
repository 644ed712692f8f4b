"""Layered encoding with rate control: a size budget or an error target per material.

Given a material's base code, its decode and its source, :func:`encode_layers`
picks the detail layer's quantisation step from a fixed ladder
(:data:`STEP_LADDER`, halving every two rungs):

- ``bytes_budget=N``: of the rungs whose record payload (μ, σ and the
  layer) fits in N bytes, and the base alone, the one with the lowest
  kept-slice mapped L1 error — the largest quality within N bytes;
- ``max_relae=X``: the coarsest rung whose decoded table has a measured
  RelAE (mapped or linear, full table, valid entries) of at most X — the
  smallest file that meets X; a base-only record when the base meets X.

Both searches bisect the ladder (size falls and error rises with the step),
then bisect the step in log space between the two rungs that bracket the
target (3 rounds for a budget, 2 for an error target), and return the best
of every step actually tried, so the answer is the smallest tried file that
meets the target even where the curve is not monotonic. The achieved RelAE
is measured on the returned record.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.bvae_format import LatentRecord
from brdfcodec.conventions import MAPPED_MAX
from brdfcodec.errors import RateTargetError
from brdfcodec.layers.detail import DetailLayer, decode_detail, encode_detail
from brdfcodec.layers.record import LayeredRecord
from brdfcodec.metrics import error_report
from brdfcodec.transforms import table_from_network_output

__all__ = ["STEP_LADDER", "Metric", "RateResult", "encode_layers", "layered_mapped"]

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
        μ, σ and the layer, as stored.
    tried : list of (step or None, payload bytes, RelAE or None)
        Every candidate evaluated (None step: base only).
    """

    record: LatentRecord
    payload_bytes: int
    tried: list[tuple[float | None, int, float | None]]


def layered_mapped(base_mapped: np.ndarray, record: LatentRecord) -> np.ndarray:
    """Base decode plus the record's detail layer, if any (mapped, network layout)."""
    if isinstance(record, LayeredRecord) and record.detail is not None:
        return base_mapped + decode_detail(record.detail).reshape(base_mapped.shape)
    return base_mapped


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
) -> RateResult:
    """A base record, layered to a size budget, an error target or a fixed step.

    Parameters
    ----------
    base : LatentRecord
        The base (refined μ, σ, meta).
    base_mapped : ndarray, shape (63, 90, 90)
        Decoder output of ``base.mu``.
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
        A fixed quantisation step instead of a target.
    latent_itemsize : int
        Bytes per stored latent value (4: float32, 2: float16).

    Raises
    ------
    RateTargetError
        The budget is below the base record's size, or no rung meets ``max_relae``.
    """
    if sum(x is not None for x in (bytes_budget, max_relae, step)) != 1:
        raise ValueError("give exactly one of bytes_budget, max_relae or step")
    if metric not in ("mapped", "linear"):
        raise ValueError(f"metric must be 'mapped' or 'linear', got {metric!r}")
    residual = (np.asarray(inputs, dtype=np.float64) - base_mapped) * np.asarray(masks)
    base_bytes = 2 * base.latent_dim * latent_itemsize
    layers: dict[float, DetailLayer] = {}

    def layer(s: float) -> DetailLayer:
        if s not in layers:
            layers[s] = encode_detail(residual, s)
        return layers[s]

    def record_of(s: float | None) -> LatentRecord:
        if s is None:
            return base
        return LayeredRecord(base.name, base.mu, base.sigma, base.meta, detail=layer(s))

    def size(s: float | None) -> int:
        return base_bytes + (0 if s is None else layer(s).nbytes)

    if step is not None:
        return RateResult(record_of(float(step)), size(float(step)), [(float(step), size(float(step)), None)])
    tried: list[tuple[float | None, int, float | None]] = []
    if bytes_budget is not None:
        if bytes_budget < base_bytes:
            raise RateTargetError(f"{base.name}: {bytes_budget} bytes is below the base record's {base_bytes} bytes")
        candidates: list[float | None] = [None, *STEP_LADDER]
        lo, hi = 0, len(candidates)  # candidates[lo] fits (the base does); candidates[hi] does not (or is past the end)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            tried.append((candidates[mid], size(candidates[mid]), None))
            if size(candidates[mid]) <= bytes_budget:
                lo = mid
            else:
                hi = mid
        if lo > 0 and hi < len(candidates):  # between two rungs: a few halvings of the step ratio, in log space
            fine, coarse = candidates[hi], candidates[lo]
            for _ in range(_REFINE_ROUNDS):
                mid_step = float(np.sqrt(fine * coarse))  # type: ignore[operator]
                tried.append((mid_step, size(mid_step), None))
                if size(mid_step) <= bytes_budget:
                    coarse = mid_step
                else:
                    fine = mid_step
        # Among the fitting candidates, the lowest kept-slice L1 error (a very coarse layer can be worse than none).
        weights = np.asarray(masks, dtype=np.float32)
        target = np.asarray(inputs, dtype=np.float32)

        def slice_error(s: float | None) -> float:
            mapped = np.clip(layered_mapped(base_mapped.copy(), record_of(s)), 0.0, MAPPED_MAX)
            return float((np.abs(mapped - target) * weights).sum())

        fitting = {None, *(s for s, n, _ in tried if n <= bytes_budget)}
        chosen = min(fitting, key=slice_error)
        return RateResult(record_of(chosen), size(chosen), tried)
    assert max_relae is not None
    if values is None or mask is None:
        raise ValueError(f"{base.name}: max_relae needs the source table to measure the error")
    if not max_relae > 0:
        raise ValueError(f"max_relae must be > 0, got {max_relae}")
    errors: dict[float | None, float] = {}

    def error(s: float | None) -> float:
        if s not in errors:
            table = table_from_network_output(layered_mapped(base_mapped, record_of(s))).astype(np.float64)
            report = error_report(values, table, mask)
            errors[s] = (report.relae_mapped if metric == "mapped" else report.relae_linear).overall
        return errors[s]

    bracket = _bisect(lambda s: error(s) <= max_relae, tried, size, error)
    if bracket is None:
        best = min(errors.values())
        raise RateTargetError(
            f"{base.name}: RelAE ({metric}) {max_relae} is not reachable; the finest step reaches {best:.4g}"
        )
    failing, meeting = bracket
    if failing is not None and meeting is not None:  # between two rungs: look for a coarser step that still meets X
        for _ in range(_REFINE_ROUNDS - 1):
            mid_step = float(np.sqrt(failing * meeting))
            ok = error(mid_step) <= max_relae
            tried.append((mid_step, size(mid_step), error(mid_step)))
            if ok:
                meeting = mid_step
            else:
                failing = mid_step
    candidates = [s for s in errors if errors[s] <= max_relae]
    chosen = min(candidates, key=size)
    return RateResult(record_of(chosen), size(chosen), tried)


def _bisect(
    ok: Callable[[float | None], bool],
    tried: list[tuple[float | None, int, float | None]],
    size: Callable[[float | None], int],
    error: Callable[[float | None], float] | None,
) -> tuple[float | None, float | None] | None:
    """Bracket the coarsest candidate (base only, then the ladder from coarse to fine) for which ``ok`` holds.

    Returns ``(last failing, first passing)`` — ``(None, None)`` when the base
    passes — or None when even the finest rung fails. ``ok`` is assumed to
    hold from some rung on.
    """
    candidates: list[float | None] = [None, *STEP_LADDER]

    def check(i: int) -> bool:
        result = ok(candidates[i])
        tried.append((candidates[i], size(candidates[i]), error(candidates[i]) if error else None))
        return result

    if check(0):
        return None, None
    lo, hi = 0, len(candidates) - 1  # ok(lo) false
    if not check(hi):
        return None
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if check(mid):
            hi = mid
        else:
            lo = mid
    return candidates[lo], candidates[hi]
