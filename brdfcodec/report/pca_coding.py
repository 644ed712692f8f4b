"""The strong classical baselines (issue 48): PCA coefficients transform-coded and entropy-coded.

A PCA basis fitted on the training materials (:mod:`brdfcodec.models.pca`)
turns a material into coefficients ``c`` (mapped units); the training
coefficients' standard deviations ``σᵢ`` (``PcaBasis.scale``) are shared
with the basis. Two coders of ``c`` for a budget of N bytes per material,
each a real encoder and decoder of bytes:

- :class:`TransformCodedPca` (fixed rate): bit widths per coefficient from
  reverse water-filling on ``σᵢ²`` (:func:`~brdfcodec.layers.bit_allocation.allocate_bits`,
  ``8·(N − 1)`` bits, at most 16 a coefficient; fixed for the budget, shared
  like the basis), a uniform mid-rise quantiser of ``2^bᵢ`` levels on
  ``[−wᵢ, wᵢ]`` with ``wᵢ = g·κ(bᵢ)·σᵢ`` (``κ(b)``: the loading of the
  uniform quantiser of a unit Gaussian with the least squared error; the
  coefficients with no bit decode to 0), and one **gain byte** per material
  ``g = 2^((G − 128)/32)``, chosen to minimise the material's squared error
  (the clip range). Payload: the gain byte, then the indices bit-packed
  (MSB first, coefficient order): ``1 + ⌈Σbᵢ/8⌉ = N`` bytes.
- :class:`EntropyCodedPca` (variable rate, at most N bytes): one uniform step
  ``Δ`` for every coefficient (the high-rate optimum of entropy-coded
  scalar quantisation), ``qᵢ = round(cᵢ/Δ)``, range-coded
  (:func:`~brdfcodec.layers.entropy_coding.encode_integers`) under a
  quantised Laplace (or Gaussian) prior of standard deviation ``σᵢ/Δ`` bins,
  each bounded at ``⌈32σᵢ/Δ⌉`` bins (rounded up to ``2^m − 1``). ``Δ = Δ_N·2^((128 − J)/32)``, where
  ``Δ_N = √(12θ)`` is the step whose squared error ``Δ²/12`` is the water
  level θ of reverse water-filling for ``8·(N − 1)`` bits
  (:func:`~brdfcodec.layers.bit_allocation.reverse_water_filling`; fixed for
  the budget, shared like the basis; raised where needed so that the bounds
  stay within ``MAX_BOUND`` at J = 255); the **step byte** J (charged) is the
  largest that keeps the material within N bytes (binary search over J;
  every tried J is coded for real). Payload: J,
  then the coder's bytes, terminated as short as decoding allows.

Both count every byte they write; nothing about a material is stored
elsewhere. numpy and constriction only (the basis' projection is done by the
caller).

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> spreads = np.array([8.0, 4.0, 2.0, 1.0, 0.5, 0.25])
>>> c = rng.normal(0, spreads)
>>> coder = TransformCodedPca(spreads, 4)
>>> coder.bits.tolist(), len(coder.encode(c))
([7, 6, 5, 3, 2, 1], 4)
>>> bool(np.sum((coder.decode(coder.encode(c)) - c) ** 2) < np.sum(c ** 2))
True
>>> ec = EntropyCodedPca(spreads, 4)
>>> len(ec.encode(c)) <= 4
True
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from brdfcodec.layers.bit_allocation import allocate_bits, reverse_water_filling
from brdfcodec.layers.entropy_coding import MAX_BOUND, Prior, decode_integers, encode_integers

__all__ = ["CODED_PCA_KINDS", "EntropyCodedPca", "TransformCodedPca", "coded_pca_rows", "gaussian_loading"]

#: The coded PCA points of :func:`coded_pca_rows`, as suffixes of the basis' name.
CODED_PCA_KINDS = ("tc", "ec-laplace", "ec-gaussian")

#: Most bits one coefficient may take in the transform coder.
MAX_COEFFICIENT_BITS = 16
#: Gain codes: g = 2^((G − 128) / GAIN_STEPS_PER_OCTAVE).
GAIN_STEPS_PER_OCTAVE = 32
#: Step codes of the entropy coder: Δ = Δ_N · 2^((128 − J) / STEP_CODES_PER_OCTAVE).
STEP_CODES_PER_OCTAVE = 32
#: The entropy coder's bound of coefficient i, in its spreads: ⌈BOUND_SPREADS · σᵢ/Δ⌉ bins.
BOUND_SPREADS = 32.0


def _spreads(spreads: npt.ArrayLike) -> npt.NDArray[np.float64]:
    s = np.asarray(spreads, dtype=np.float64)
    if s.ndim != 1 or len(s) == 0 or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError("spreads must be a non-empty 1-D array of finite values > 0")
    return s


@functools.lru_cache(maxsize=None)
def gaussian_loading(bits: int) -> float:
    """κ(b): the half-width (in standard deviations) of the ``2^b``-level uniform mid-rise quantiser of a unit
    Gaussian with the least mean squared error.

    Exact integrals per cell, minimised by golden-section search for ``b ≤ 10``; beyond, extended linearly (a
    slight overestimate, harmless where the cells are this fine).

    Parameters
    ----------
    bits : int
        b ≥ 1 (bits).

    Returns
    -------
    float
        Standard deviations.

    >>> round(gaussian_loading(1), 3), round(gaussian_loading(2), 3)
    (1.596, 1.991)
    """
    if bits < 1:
        raise ValueError(f"bits must be ≥ 1, got {bits}")
    if bits > 10:
        return gaussian_loading(10) + (bits - 10) * (gaussian_loading(10) - gaussian_loading(9))
    levels = 2**bits
    erf = np.vectorize(math.erf, otypes=[np.float64])

    def mse(half_width: float) -> float:
        step = 2.0 * half_width / levels
        edges = -half_width + step * np.arange(1, levels)
        a = np.concatenate([[-np.inf], edges])
        b = np.concatenate([edges, [np.inf]])
        r = -half_width + step * (np.arange(levels) + 0.5)
        def big_phi(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
            return 0.5 * (1.0 + erf(x / math.sqrt(2.0)))

        def phi(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:  # 0 at ±inf
            finite = np.where(np.isfinite(x), x, 0.0)
            return np.where(np.isfinite(x), np.exp(-0.5 * finite**2), 0.0) / math.sqrt(2.0 * math.pi)

        def x_phi(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:  # x·φ(x), 0 at ±inf
            return np.where(np.isfinite(x), np.where(np.isfinite(x), x, 0.0) * phi(x), 0.0)

        mass = big_phi(b) - big_phi(a)
        # ∫ₐᵇ (x − r)² φ = (1 + r²)(Φ(b) − Φ(a)) − (bφ(b) − aφ(a)) − 2r(φ(a) − φ(b))
        return float(np.sum((1.0 + r * r) * mass - (x_phi(b) - x_phi(a)) - 2.0 * r * (phi(a) - phi(b))))

    lo, hi = 0.1, 8.0
    ratio = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):
        m1, m2 = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        if mse(m1) <= mse(m2):
            hi = m2
        else:
            lo = m1
    return 0.5 * (lo + hi)


class TransformCodedPca:
    """Fixed-rate transform coding of PCA coefficients in ``budget_bytes`` bytes (see the module docstring).

    Parameters
    ----------
    spreads : array_like of float, shape (k,)
        σᵢ of each coefficient over the training materials, > 0 (mapped units).
    budget_bytes : int
        N ≥ 1: the gain byte plus ``8·(N − 1)`` bits of indices (bytes).

    Attributes
    ----------
    bits : ndarray of int64, shape (k,)
        Bits per coefficient (reverse water-filling in whole bits, at most 16 each).
    payload_bytes : int
        Bytes of every payload: ``1 + ⌈Σbᵢ/8⌉`` (≤ N).
    """

    def __init__(self, spreads: npt.ArrayLike, budget_bytes: int) -> None:
        self.spreads = _spreads(spreads)
        if int(budget_bytes) != budget_bytes or budget_bytes < 1:
            raise ValueError(f"budget_bytes must be a whole number ≥ 1, got {budget_bytes!r}")
        self.bits = allocate_bits(self.spreads**2, 8 * (int(budget_bytes) - 1), max_bits=MAX_COEFFICIENT_BITS)
        self.payload_bytes = 1 + math.ceil(int(self.bits.sum()) / 8)
        active = self.bits > 0
        self._active = np.flatnonzero(active)
        self._levels = (2 ** self.bits[active]).astype(np.int64)
        self._half = np.array([gaussian_loading(int(b)) for b in self.bits[active]]) * self.spreads[active]
        self._gains = 2.0 ** ((np.arange(256) - 128) / GAIN_STEPS_PER_OCTAVE)

    def _quantise(self, values: npt.NDArray[np.float64], gains: npt.NDArray[np.float64]) -> tuple[
            npt.NDArray[np.int64], npt.NDArray[np.float64]]:
        half = gains[:, None] * self._half[None, :]
        step = 2.0 * half / self._levels
        index = np.clip(np.floor((values[None, :] + half) / step), 0, self._levels - 1).astype(np.int64)
        return index, -half + (index + 0.5) * step

    def encode(self, coefficients: npt.ArrayLike) -> bytes:
        """The payload of one material's coefficients ``(k,)``: the gain byte, then the packed indices."""
        c = np.asarray(coefficients, dtype=np.float64)
        if c.shape != self.spreads.shape or not np.all(np.isfinite(c)):
            raise ValueError(f"coefficients must be finite of shape {self.spreads.shape}, got {c.shape}")
        values = c[self._active]
        indices, decoded = self._quantise(values, self._gains)
        gain = int(np.argmin(np.sum((decoded - values[None, :]) ** 2, axis=1)))
        widths = self.bits[self._active]
        shifts = np.arange(MAX_COEFFICIENT_BITS)
        used = shifts[None, :] < widths[:, None]
        bit_values = (indices[gain][:, None] >> np.maximum(widths[:, None] - 1 - shifts[None, :], 0)) & 1
        packed = np.packbits(bit_values[used].astype(np.uint8)).tobytes()
        return bytes([gain]) + packed

    def decode(self, payload: bytes) -> npt.NDArray[np.float64]:
        """The coefficients ``(k,)`` of a payload written by :meth:`encode` (0 where no bit was spent)."""
        if len(payload) != self.payload_bytes:
            raise ValueError(f"a payload of this coder has {self.payload_bytes} bytes, got {len(payload)}")
        gain = payload[0]
        widths = self.bits[self._active]
        flat = np.unpackbits(np.frombuffer(payload[1:], dtype=np.uint8))[: int(widths.sum())].astype(np.int64)
        shifts = np.arange(MAX_COEFFICIENT_BITS)
        used = shifts[None, :] < widths[:, None]
        bit_values = np.zeros(used.shape, dtype=np.int64)
        bit_values[used] = flat
        weights = np.where(used, 2 ** np.maximum(widths[:, None] - 1 - shifts[None, :], 0), 0)
        indices = np.sum(bit_values * weights, axis=1)
        half = self._gains[gain] * self._half
        step = 2.0 * half / self._levels
        out = np.zeros(len(self.spreads))
        out[self._active] = -half + (indices + 0.5) * step
        return out


class EntropyCodedPca:
    """Entropy-coded PCA coefficients within ``budget_bytes`` bytes, one step per material (module docstring).

    Parameters
    ----------
    spreads : array_like of float, shape (k,)
        σᵢ of each coefficient over the training materials, > 0 (mapped units): the priors' spreads.
    budget_bytes : int
        N ≥ 2: the step byte and the coder's bytes stay within it (bytes).
    prior : {"laplace", "gaussian"}, optional
        The prior's density (default Laplace).
    """

    def __init__(self, spreads: npt.ArrayLike, budget_bytes: int, prior: Prior = "laplace") -> None:
        self.spreads = _spreads(spreads)
        if int(budget_bytes) != budget_bytes or budget_bytes < 2:
            raise ValueError(f"budget_bytes must be a whole number ≥ 2, got {budget_bytes!r}")
        if prior not in ("laplace", "gaussian"):
            raise ValueError(f"prior must be 'laplace' or 'gaussian', got {prior!r}")
        self.budget_bytes, self.prior = int(budget_bytes), prior
        level = reverse_water_filling(self.spreads**2, 8 * (self.budget_bytes - 1)).level
        #: Δ_N: the reference step of the budget (mapped units).
        # No finer than the step at which the largest coefficient's bound reaches MAX_BOUND (at code 255).
        floor = BOUND_SPREADS * float(self.spreads.max()) / MAX_BOUND
        self.reference_step = max(math.sqrt(12.0 * level), floor * 2.0 ** ((255 - 128) / STEP_CODES_PER_OCTAVE))
        #: The finest step code whose bounds stay within MAX_BOUND (0 … 255).
        self.finest_code = 255
        while self.finest_code > 0 and BOUND_SPREADS * self.spreads.max() / self.step(self.finest_code) > MAX_BOUND:
            self.finest_code -= 1

    def step(self, code: int) -> float:
        """Δ of step code J (mapped units)."""
        return self.reference_step * 2.0 ** ((128 - code) / STEP_CODES_PER_OCTAVE)

    def _bounds(self, step: float) -> npt.NDArray[np.int64]:
        # ⌈32σᵢ/Δ⌉ rounded up to 2^m − 1, so that few groups of equal bounds are coded (and coding is fast).
        wanted = np.clip(np.ceil(BOUND_SPREADS * self.spreads / step), 1, MAX_BOUND)
        return np.minimum(2 ** np.ceil(np.log2(wanted + 1)) - 1, MAX_BOUND).astype(np.int64)

    def _code(self, c: npt.NDArray[np.float64], code: int) -> bytes:
        step = self.step(code)
        bounds = self._bounds(step)
        q = np.clip(np.rint(c / step), -bounds, bounds).astype(np.int64)
        return bytes([code]) + encode_integers(q, self.spreads / step, bound=bounds, prior=self.prior)

    def encode(self, coefficients: npt.ArrayLike) -> bytes:
        """The payload of one material's coefficients ``(k,)``: the finest step code that fits, then the coder's
        bytes. At most ``budget_bytes`` bytes.

        Raises
        ------
        ValueError
            Coefficients of another shape or not finite; not even all-zero coefficients fit the budget. (Where
            the coarsest step does not fit, the leading coefficients that fit are kept and the rest coded as 0.)
        """
        c = np.asarray(coefficients, dtype=np.float64)
        if c.shape != self.spreads.shape or not np.all(np.isfinite(c)):
            raise ValueError(f"coefficients must be finite of shape {self.spreads.shape}, got {c.shape}")
        best = self._code(c, 0)
        if len(best) > self.budget_bytes:
            return self._truncated(c)
        # lo fits; find the largest code that fits (bytes grow with the code, nearly always), among the codes
        # whose bounds all stay below MAX_BOUND (finer steps would clip the largest coefficients).
        lo, hi = 0, self.finest_code
        if hi == 0:
            return best
        top = self._code(c, hi)
        if len(top) <= self.budget_bytes:
            return top
        while hi - lo > 1:
            mid = (lo + hi) // 2
            trial = self._code(c, mid)
            if len(trial) <= self.budget_bytes:
                lo, best = mid, trial
            else:
                hi = mid
        return best

    def _truncated(self, c: npt.NDArray[np.float64]) -> bytes:
        """At the coarsest step, the most leading coefficients that fit, the rest coded as 0 (a material far
        outside the training spread, whose clipped coefficients cost more than the budget: rare, at small N)."""
        zeros = np.zeros_like(c)
        best = self._code(zeros, 0)
        if len(best) > self.budget_bytes:
            raise ValueError(f"no step fits {self.budget_bytes} bytes")
        lo, hi = 0, len(c)  # lo leading coefficients fit; all of them do not
        while hi - lo > 1:
            mid = (lo + hi) // 2
            trial = self._code(np.concatenate([c[:mid], zeros[mid:]]), 0)
            if len(trial) <= self.budget_bytes:
                lo, best = mid, trial
            else:
                hi = mid
        return best

    def decode(self, payload: bytes) -> npt.NDArray[np.float64]:
        """The coefficients ``(k,)`` of a payload written by :meth:`encode` (mapped units)."""
        if not payload:
            raise ValueError("an empty payload has no step byte")
        step = self.step(payload[0])
        q = decode_integers(payload[1:], self.spreads / step, bound=self._bounds(step), prior=self.prior)
        return q.astype(np.float64) * step


def coded_pca_rows(name: str, basis: Any, inputs: npt.NDArray[Any], references: Sequence[Any],
                   budgets: Sequence[int], error: Callable[[Any, npt.NDArray[Any]], tuple[float, float]]
                   ) -> list[dict[str, Any]]:
    """Rows of the coded PCA points at each budget: ``{name}-tc``, ``{name}-ec-laplace``, ``{name}-ec-gaussian``.

    Each material is projected on all the basis' components, encoded to bytes, decoded from them, clamped
    to the mapped domain and scored against its reference.

    Parameters
    ----------
    name : str
        The basis' point name (``"pca"``, ``"pca-perm"``).
    basis : PcaBasis
        Fitted on the training materials; its ``scale`` (the training coefficients' standard deviations) are
        the coders' spreads.
    inputs : ndarray, shape (M, 63, 90, 90)
        The materials' mapped inputs.
    references : sequence of MerlBRDF
        The materials' tables, in the same order.
    budgets : sequence of int
        Bytes per material.
    error : callable
        ``error(reference, table) → (mapped RelAE, linear RelAE)``.

    Returns
    -------
    list of dict
        One row per point and budget: ``point``, ``budget_bytes``, ``coefficients`` (the basis' size, or those
        given bits), ``bytes_per_material`` (mean payload bytes), ``bytes_max``, and the errors
        (``mapped_relae_mean``, ``mapped_relae_median``, ``linear_relae_mean``, ``per_material_mapped``) and the
        decode time per material from the payload to the full table (``decode_ms_median``, ``decode_ms_mean``).
    """
    from brdfcodec.conventions import MAPPED_MAX
    from brdfcodec.representation import table_from_network_output

    components = basis.components
    coefficients = (inputs.reshape(len(inputs), -1) - basis.mean) @ components.T
    spreads = np.asarray(basis.scale, dtype=np.float64)
    rows = []
    for budget in budgets:
        coders: list[tuple[str, Any, int]] = []
        if budget >= 2:
            tc = TransformCodedPca(spreads, budget)
            coders.append((f"{name}-tc", tc, int(np.count_nonzero(tc.bits))))
            priors: tuple[Prior, ...] = ("laplace", "gaussian")
            coders += [(f"{name}-ec-{prior}", EntropyCodedPca(spreads, budget, prior), len(spreads))
                       for prior in priors]
        for point, coder, count in coders:
            sizes, errors, seconds = [], [], []
            for c, reference in zip(coefficients, references, strict=True):
                payload = coder.encode(c)
                sizes.append(len(payload))
                start = time.perf_counter()  # timed: the payload's bytes to the full table
                decoded = coder.decode(payload).astype(np.float32)
                mapped = np.clip(decoded @ components + basis.mean, 0.0, MAPPED_MAX).reshape(63, 90, 90)
                table = table_from_network_output(mapped)
                seconds.append(time.perf_counter() - start)
                errors.append(error(reference, table))
            mapped_errors = np.array([e[0] for e in errors])
            rows.append({"point": point, "budget_bytes": int(budget), "coefficients": count,
                         "bytes_per_material": float(np.mean(sizes)), "bytes_max": int(max(sizes)),
                         "mapped_relae_mean": float(mapped_errors.mean()),
                         "mapped_relae_median": float(np.median(mapped_errors)),
                         "linear_relae_mean": float(np.mean([e[1] for e in errors])),
                         "per_material_mapped": [float(v) for v in mapped_errors],
                         "decode_ms_median": 1e3 * float(np.median(seconds)),
                         "decode_ms_mean": 1e3 * float(np.mean(seconds))})
    return rows
