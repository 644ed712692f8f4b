"""Bit allocation for transform coding: reverse water-filling over coefficients of known variance.

A transform coder (PCA, DCT, a shared basis) quantises each coefficient ``i``
of variance ``σᵢ²`` on its own. Under the classical model of the
distortion–rate function of each coefficient, ``Dᵢ(Rᵢ) = σᵢ² · 2^(−2Rᵢ)``
(squared error in the coefficient's units; exact for a Gaussian source, a
high-rate approximation for others), the split of a budget of ``R`` bits
that minimises the summed squared error ``Σ Dᵢ`` is **reverse
water-filling**: a level ``θ`` such that every coefficient with ``σᵢ² > θ``
gets ``Rᵢ = ½·log₂(σᵢ²/θ)`` bits and error ``θ``, and every other gets no bit
and keeps its variance as error (Cover & Thomas, *Elements of Information
Theory*, §10.3.3).

- :func:`reverse_water_filling` solves the continuous problem exactly
  (real-valued bits, the level ``θ`` and the distortion it predicts);
- :func:`allocate_bits` gives whole bits per coefficient (what a scalar
  quantiser of ``2^b`` levels spends): the greedy solution of the same
  problem, one bit at a time to the coefficient whose error it lowers most.
  It is optimal for the model above, deterministic (ties go to the lower
  index) and nested: the allocation for ``R + 1`` bits is the one for
  ``R`` plus one bit, so every coefficient's bits are non-decreasing in the
  budget;
- :func:`predicted_distortion` is the model's ``Σ σᵢ²·2^(−2bᵢ)``.

Units: variances in squared coefficient units (any), bits in bits, budgets in
bits (whole bits for :func:`allocate_bits`). numpy only.

>>> import numpy as np
>>> solution = reverse_water_filling([4.0, 1.0, 0.25], 2.0)
>>> np.round(solution.bits, 6), round(solution.level, 6), round(solution.distortion, 6)
(array([1.5, 0.5, 0. ]), 0.5, 1.25)
>>> allocate_bits([4.0, 1.0, 0.25], 3)
array([2, 1, 0])
>>> float(predicted_distortion([4.0, 1.0, 0.25], [2, 1, 0]))
0.75
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["WaterFilling", "allocate_bits", "predicted_distortion", "reverse_water_filling"]


@dataclass(frozen=True)
class WaterFilling:
    """The solution of reverse water-filling for one budget.

    Attributes
    ----------
    bits : ndarray of float64, shape (n,)
        Bits per coefficient, ≥ 0 (bits); they sum to the budget.
    level : float
        The water level θ: the squared error of every coefficient that gets bits (variance units); ``inf``
        when the budget is 0 or every variance is 0.
    distortion : float
        The summed squared error ``Σ min(θ, σᵢ²)`` the model predicts (variance units).
    """

    bits: npt.NDArray[np.float64]
    level: float
    distortion: float


def _variances(variances: npt.ArrayLike) -> npt.NDArray[np.float64]:
    v = np.asarray(variances, dtype=np.float64)
    if v.ndim != 1:
        raise ValueError(f"variances must be a 1-D array, got shape {v.shape}")
    if not np.all(np.isfinite(v)) or np.any(v < 0):
        raise ValueError("variances must be finite and ≥ 0")
    return v


def _budget(total_bits: float) -> float:
    budget = float(total_bits)
    if not np.isfinite(budget) or budget < 0:
        raise ValueError(f"the bit budget must be finite and ≥ 0, got {total_bits!r}")
    return budget


def reverse_water_filling(variances: npt.ArrayLike, total_bits: float) -> WaterFilling:
    """Split ``total_bits`` among coefficients of the given variances to minimise the summed squared error.

    Parameters
    ----------
    variances : array_like of float, shape (n,)
        σᵢ² of each coefficient, ≥ 0 (squared coefficient units).
    total_bits : float
        The budget R, ≥ 0 (bits; real-valued).

    Returns
    -------
    WaterFilling
        Bits per coefficient ``max(0, ½·log₂(σᵢ²/θ))`` summing to R (to rounding), the level θ and the
        predicted distortion ``Σ min(θ, σᵢ²)``.

    Raises
    ------
    ValueError
        Variances not 1-D, negative or not finite; a negative or non-finite budget.

    Notes
    -----
    Exact: with the variances sorted in decreasing order, the ``k`` largest are active when
    ``θₖ = (Πⱼ≤ₖ σⱼ²)^(1/k) · 2^(−2R/k)`` lies in ``[σₖ₊₁², σₖ²)``; the first such ``k`` (the
    only one) is taken.
    """
    v = _variances(variances)
    budget = _budget(total_bits)
    bits = np.zeros(len(v), dtype=np.float64)
    positive = v > 0
    if budget == 0 or not positive.any():
        return WaterFilling(bits, float("inf"), float(v.sum()))
    order = np.argsort(-v, kind="stable")
    ranked = v[order]
    logs = np.log2(ranked[ranked > 0])
    level_log = float(logs[0] - 2.0 * budget)
    for k in range(1, len(logs) + 1):
        candidate = (float(logs[:k].sum()) - 2.0 * budget) / k  # log2 θₖ
        level_log = candidate
        if k == len(logs) or candidate >= logs[k]:
            break
    level = float(2.0**level_log)
    active = ranked > level
    ranked_bits = np.where(active, 0.5 * (np.log2(np.where(active, ranked, 1.0)) - level_log), 0.0)
    bits[order] = ranked_bits
    return WaterFilling(bits, level, float(np.minimum(v, level).sum()))


def allocate_bits(variances: npt.ArrayLike, total_bits: int, *, max_bits: int = 16) -> npt.NDArray[np.int64]:
    """Whole bits per coefficient for a budget: reverse water-filling in integers (greedy, nested).

    Each bit goes to the coefficient whose modelled error ``σᵢ²·2^(−2bᵢ)`` is largest (it lowers that error
    by three quarters), ties to the lower index, until the budget is spent or every coefficient holds
    ``max_bits``. Coefficients of variance 0 get no bit.

    Parameters
    ----------
    variances : array_like of float, shape (n,)
        σᵢ² of each coefficient, ≥ 0 (squared coefficient units).
    total_bits : int
        The budget, ≥ 0 (bits).
    max_bits : int, optional
        The most bits one coefficient may take, in [1, 62] (bits; default 16).

    Returns
    -------
    ndarray of int64, shape (n,)
        Bits per coefficient in ``[0, max_bits]``; they sum to ``min(total_bits, max_bits · #{σᵢ² > 0})``.
        The allocation for a larger budget holds at least as many bits for every coefficient.

    Raises
    ------
    ValueError
        Variances not 1-D, negative or not finite; a budget that is negative or not a whole number;
        ``max_bits`` outside [1, 62].
    """
    v = _variances(variances)
    if int(total_bits) != total_bits or total_bits < 0:
        raise ValueError(f"the bit budget must be a whole number ≥ 0, got {total_bits!r}")
    if not 1 <= int(max_bits) <= 62:
        raise ValueError(f"max_bits must be in [1, 62], got {max_bits!r}")
    bits = np.zeros(len(v), dtype=np.int64)
    # The error is compared as (log2 σ², −index): the greedy step is exact in log2 (each bit subtracts 2).
    logs = np.log2(np.where(v > 0, v, 1.0))
    heap = [(-float(logs[i]), i) for i in np.flatnonzero(v > 0).tolist()]
    heapq.heapify(heap)
    for _ in range(int(total_bits)):
        if not heap:
            break
        negative_log, i = heapq.heappop(heap)
        bits[i] += 1
        if bits[i] < max_bits:
            heapq.heappush(heap, (negative_log + 2.0, i))
    return bits


def predicted_distortion(variances: npt.ArrayLike, bits: npt.ArrayLike) -> float:
    """The model's summed squared error ``Σ σᵢ²·2^(−2bᵢ)`` for bits per coefficient.

    Parameters
    ----------
    variances : array_like of float, shape (n,)
        σᵢ², ≥ 0 (squared coefficient units).
    bits : array_like of float, shape (n,)
        Bits per coefficient, ≥ 0 (bits; whole or real).

    Returns
    -------
    float
        Squared coefficient units.

    Raises
    ------
    ValueError
        Shapes that differ, negative or non-finite values.
    """
    v = _variances(variances)
    b = np.asarray(bits, dtype=np.float64)
    if b.shape != v.shape:
        raise ValueError(f"bits have shape {b.shape}, variances {v.shape}")
    if not np.all(np.isfinite(b)) or np.any(b < 0):
        raise ValueError("bits must be finite and ≥ 0")
    return float(np.sum(v * np.exp2(-2.0 * b)))
