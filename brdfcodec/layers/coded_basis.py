"""Entropy-coded basis coefficients under declared Laplace priors (``spec/bvae-format.md`` §4.8, format 2.4).

A transform coder spends its bits where the variance is: every coefficient is
quantised with one step s, and the integers are arithmetic-coded under a
zero-mean Laplace prior whose spread falls with the basis vector's rank, as
the shared basis' training spread does. The prior is a power law declared
once per record form — the spread of vector n (1-based) is

    σₙ = 2^(A/16 − 4) · n^(−d/32)        (mapped units)

for the form's two bytes A (amplitude) and d (decay) — so a decoder needs no
table beside the file: decoding is exact integer arithmetic.

- *Prior code* of coefficient i (vector n = f + i + 1) at step code e
  (s = 2^(e/16 − 8), as a packed layer's, :func:`~brdfcodec.layers.packed.packed_step`):
  cᵢ = A − e + 64 − ⌊(d·L(n) + 32) / 64⌋, L(n) = round(32·log₂ n) computed exactly in integers
  (16·log₂(σₙ/s) rounded), clipped to ``[-PRIOR_CODE_LIMIT, PRIOR_CODE_LIMIT]``.
- *Binarisation* of an integer q under prior code c: a bit "q ≠ 0" with probability
  ``ZERO_PROBABILITY[c]`` of 0; if set, a sign bit (1: negative) at 128, then the magnitude m = |q| as
  bits "m > j" for j = 1 … 14 with probability ``STOP_PROBABILITY[c]`` of 0, stopping at the first 0; at
  m ≥ 15 the rest m − 15 in Exp-Golomb order 0 at probability 128 (a prefix of at most
  ``MAX_ESCAPE_PREFIX`` ones, then a 0, then the prefix's count of low bits of m − 14, most significant first).
- *Coder*: the boolean entropy coder of RFC 6386 §7 (8-bit probabilities of the bit being 0); the decoder
  reads zero bytes past the layer's end, so the writer keeps the shortest byte string that decodes to the
  same bits (:func:`encode_integers`).

Probabilities (in 1/256, of the bit being 0) come from the prior: with b = σ / (√2 s) the Laplace scale in
steps, P(q = 0) = 1 − exp(−1/(2b)) and P(m = j | m ≥ j) = 1 − exp(−1/b), each rounded to the nearest
integer of 256·P and clipped to 1 … 255 (:data:`ZERO_PROBABILITY`, :data:`STOP_PROBABILITY`; no entry lies
within 10⁻⁶ of a rounding boundary, so every binary64 ``exp`` gives these tables; the spec lists them).

Part of :mod:`brdfcodec.layers.basis`, which gathers the names of its parts.
"""

from __future__ import annotations

import functools
from typing import Final

import numpy as np
import numpy.typing as npt

from brdfcodec.layers.packed import packed_step

__all__ = [
    "CODED_HEADER_BYTES",
    "MAX_CODED_BYTES",
    "MAX_ESCAPE_PREFIX",
    "PRIOR_CODE_LIMIT",
    "STOP_PROBABILITY",
    "ZERO_PROBABILITY",
    "CodedChoice",
    "MAX_MU_STEP_LOG2",
    "choose_coding",
    "coded_mu_codes",
    "coded_prefix_sizes",
    "decode_integers",
    "encode_integers",
    "fit_prior_codes",
    "ideal_code_bits",
    "mu_stream_lead",
    "prior_codes",
]

#: Bytes of a coded layer before the coder's bytes: the step code.
CODED_HEADER_BYTES: Final = 1
#: Largest coded layer, bytes (step code included).
MAX_CODED_BYTES: Final = 1 << 20
#: Prior codes are clipped to ±80 (σ/s from 2⁻⁵ to 2⁵).
PRIOR_CODE_LIMIT: Final = 80
#: Finest grid of a coded μ (format 2.5): μ = q · 2^−g for g = 1 … 5, its prior codes 16·g within ±80.
MAX_MU_STEP_LOG2: Final = 5
#: Unary magnitude bits before the escape.
_UNARY: Final = 14
#: Longest Exp-Golomb prefix of an escaped magnitude (m ≤ 15 + 2²¹ − 2).
MAX_ESCAPE_PREFIX: Final = 20
#: Largest magnitude a coded layer holds.
MAX_MAGNITUDE: Final = _UNARY + (1 << (MAX_ESCAPE_PREFIX + 1)) - 1


def _probability_tables() -> tuple[tuple[int, ...], tuple[int, ...]]:
    codes = np.arange(-PRIOR_CODE_LIMIT, PRIOR_CODE_LIMIT + 1, dtype=np.float64)
    b = 2.0 ** (codes / 16) / np.sqrt(2.0)  # Laplace scale in steps
    zero = 256 * -np.expm1(-1 / (2 * b))
    stop = 256 * -np.expm1(-1 / b)
    return (tuple(int(v) for v in np.clip(np.floor(zero + 0.5), 1, 255)),
            tuple(int(v) for v in np.clip(np.floor(stop + 0.5), 1, 255)))


#: Probability (/256) that q = 0, by prior code c + :data:`PRIOR_CODE_LIMIT`.
#: Probability (/256) that the magnitude stops at j, by prior code c + :data:`PRIOR_CODE_LIMIT`.
ZERO_PROBABILITY, STOP_PROBABILITY = _probability_tables()


def _round_32_log2(n: int) -> int:
    """round(32·log₂ n) for an integer n ≥ 1, exactly: with t = ⌊log₂ n⁶⁴⌋, ⌊(t + 1) / 2⌋ (never halfway)."""
    return (int(n) ** 64).bit_length() // 2


@functools.lru_cache(maxsize=64)
def _scaled_log2(first: int, count: int) -> npt.NDArray[np.int64]:
    """L(n) = round(32·log₂ n) for n = first + 1 … first + count, exactly (read-only, cached)."""
    out = np.array([_round_32_log2(n) for n in range(first + 1, first + count + 1)], dtype=np.int64)
    out.setflags(write=False)
    return out


def prior_codes(amplitude: int, decay: int, step_code: int, first: int, count: int) -> npt.NDArray[np.int64]:
    """Prior codes cᵢ of coefficients i = 0 … k − 1 (vectors n = first + i + 1), clipped to ±80."""
    scaled = _scaled_log2(int(first), int(count))
    codes = int(amplitude) - int(step_code) + 64 - (int(decay) * scaled + 32) // 64
    return np.clip(codes, -PRIOR_CODE_LIMIT, PRIOR_CODE_LIMIT)


#: Enough ones for the longest run of set bits one integer binarises to.
_ONES: Final = (1,) * max(_UNARY, MAX_ESCAPE_PREFIX)


def coded_mu_codes(step_log2: int, latent_dim: int) -> npt.NDArray[np.int64]:
    """Prior codes of a coded μ's D integers on the grid 2^−g (format 2.5, ``spec/bvae-format.md`` §4.9): 16·g
    each, a Laplace prior of spread 1 latent unit (the β-VAE prior's) in steps of 2^−g.

    Raises
    ------
    ValueError
        g outside 1 … :data:`MAX_MU_STEP_LOG2`.
    """
    g = int(step_log2)
    if not 1 <= g <= MAX_MU_STEP_LOG2:
        raise ValueError(f"a coded mu's grid exponent must be 1 to {MAX_MU_STEP_LOG2}, got {step_log2!r}")
    return np.full(int(latent_dim), 16 * g, dtype=np.int64)


def mu_stream_lead(coded_mu: tuple[int, npt.ArrayLike]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """A coded μ ``(g, q)`` as it leads a coded layer's stream (format 2.5, ``spec/bvae-format.md`` §4.9): its D
    integers and their prior codes (:func:`coded_mu_codes`), what :func:`choose_coding`'s ``lead`` takes.

    Raises
    ------
    ValueError
        g outside 1 … :data:`MAX_MU_STEP_LOG2`.
    """
    g, q = coded_mu
    integers = np.asarray(q, dtype=np.int64).reshape(-1)
    return integers, coded_mu_codes(g, len(integers))


def _binarise(q: npt.NDArray[np.int64], codes: npt.NDArray[np.int64]) -> tuple[list[int], list[int], list[int]]:
    """The bits of integers under their prior codes, each bit's probability of 0 (/256), in coding order, and
    where each integer's bits end (the count of bits up to and including its own)."""
    bits: list[int] = []
    probabilities: list[int] = []
    ends: list[int] = []
    for value, code in zip(q.tolist(), codes.tolist(), strict=True):
        if not value:
            bits.append(0)
            probabilities.append(ZERO_PROBABILITY[code + PRIOR_CODE_LIMIT])
            ends.append(len(bits))
            continue
        m = abs(value)
        ones = min(m - 1, _UNARY)  # bits "m > j" for j = 1 … min(m, 14): ones, then a 0 where m ≤ 14
        bits += (1, int(value < 0), *_ONES[:ones], *((0,) if m <= _UNARY else ()))
        stop = STOP_PROBABILITY[code + PRIOR_CODE_LIMIT]
        probabilities += (ZERO_PROBABILITY[code + PRIOR_CODE_LIMIT], 128, *((stop,) * (ones + (m <= _UNARY))))
        if m > _UNARY:
            rest = m - _UNARY  # ≥ 1: Exp-Golomb order 0 of rest − 1
            prefix = rest.bit_length() - 1
            bits += (*_ONES[:prefix], 0, *((rest >> b) & 1 for b in range(prefix - 1, -1, -1)))
            probabilities += (128,) * (2 * prefix + 1)
        ends.append(len(bits))
    return bits, probabilities, ends


def _checked(q: npt.ArrayLike, codes: npt.ArrayLike) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    values = np.asarray(q, dtype=np.int64).reshape(-1)
    prior = np.asarray(codes, dtype=np.int64).reshape(-1)
    if values.shape != prior.shape:
        raise ValueError(f"{len(values)} integers for {len(prior)} prior codes")
    if len(prior) and int(np.abs(prior).max()) > PRIOR_CODE_LIMIT:
        raise ValueError(f"a prior code lies outside ±{PRIOR_CODE_LIMIT}")
    if len(values) and int(np.abs(values).max()) > MAX_MAGNITUDE:
        raise ValueError(f"a coded integer exceeds ±{MAX_MAGNITUDE}")
    return values, prior


def _code(values: npt.NDArray[np.int64], prior: npt.NDArray[np.int64],
          prefix_sizes: list[int] | None = None) -> tuple[int, int, int]:
    """The coder's state (low, span, shifts) after every bit of the integers; with ``prefix_sizes``, appends
    the byte length of every prefix's terminated code to it (the empty one first)."""
    low, span, shifts = 0, 255, 0
    bits, probabilities, ends = _binarise(values, prior)
    if prefix_sizes is not None:
        prefix_sizes.append(0)
    end = iter(ends)
    next_end = next(end, -1)
    for count, (bit, probability) in enumerate(zip(bits, probabilities, strict=True), start=1):
        split = 1 + (((span - 1) * probability) >> 8)
        if bit:
            low += split
            span -= split
        else:
            span = split
        if span < 128:  # renormalise: double span (and low) until it is 128 or more
            shift = 8 - span.bit_length()
            span <<= shift
            low <<= shift
            shifts += shift
        if count == next_end:
            if prefix_sizes is not None:
                prefix_sizes.append(_terminated_length(low, span, shifts))
            next_end = next(end, -1)
    return low, span, shifts


def _terminated_length(low: int, span: int, shifts: int) -> int:
    """The fewest bytes m whose value, as a binary fraction X with zeros after it, the decoder reads as the
    coded bits: low ≤ X·2^(8 + shifts) < low + span, i.e. a multiple of 2^(8 + shifts − 8m) in
    [low, low + span − 1]. Such a multiple exists for every exponent up to the highest bit where low − 1 and
    low + span − 1 differ (for every exponent where low is 0), and for no larger one."""
    if low == 0:
        return 0
    highest = ((low + span - 1) ^ (low - 1)).bit_length() - 1
    return max(0, -(-(8 + shifts - highest) // 8))


def encode_integers(q: npt.ArrayLike, codes: npt.ArrayLike) -> bytes:
    """The shortest coder bytes that :func:`decode_integers` turns back into ``q``.

    Raises
    ------
    ValueError
        A magnitude above :data:`MAX_MAGNITUDE`, or ``q`` and ``codes`` of different lengths.
    """
    low, span, shifts = _code(*_checked(q, codes))
    m = _terminated_length(low, span, shifts)
    exponent = 8 + shifts - 8 * m
    if exponent < 0:
        return (low << -exponent).to_bytes(m, "big")
    return (-(-low >> exponent)).to_bytes(m, "big")


def ideal_code_bits(q: npt.ArrayLike, codes: npt.ArrayLike) -> float:
    """The ideal code length of integers under their prior codes: −log₂ of each binarised bit's probability under
    the tables (:data:`ZERO_PROBABILITY`, :data:`STOP_PROBABILITY`, p/256 for a 0 and 1 − p/256 for a 1), summed.

    The coder's bytes (:func:`encode_integers`) come close to it for streams of a few dozen integers, the
    termination added; they can also be shorter, since the zero bits after a stream's last 1 bit cost nothing (a
    decoder reads zeros past the end), and the coder's 8-bit split is not exactly p/256 (on long streams the two
    drift apart, either way).

    Parameters
    ----------
    q : array_like of int, shape (n,)
        The integers.
    codes : array_like of int, shape (n,)
        Their prior codes, each within ±:data:`PRIOR_CODE_LIMIT`.

    Returns
    -------
    float
        Bits (≥ 0).

    Raises
    ------
    ValueError
        As :func:`encode_integers`.
    """
    bits, probabilities, _ = _binarise(*_checked(q, codes))
    zero = np.asarray(probabilities, dtype=np.float64) / 256.0
    return float(-np.log2(np.where(np.asarray(bits, dtype=bool), 1.0 - zero, zero)).sum())


def fit_prior_codes(q: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Per column of integers (rows: samples, e.g. materials' coded μ), the prior code of least ideal code length
    (:func:`ideal_code_bits`, a proxy for the coder's bytes) within ±:data:`PRIOR_CODE_LIMIT`: the spread of a
    Laplace prior fitted to each dimension, as 16·log₂(σ/s) for σ the spread and s the grid's step (the format's
    unit prior on the grid 2^−g: 16·g). Of equally short codes the smallest (narrowest) is kept: a column of zeros
    gets −:data:`PRIOR_CODE_LIMIT`.

    Parameters
    ----------
    q : array_like of int, shape (n, D)
        n ≥ 1 samples of D integers.

    Returns
    -------
    numpy.ndarray of int64, shape (D,)
        One prior code per column.

    Raises
    ------
    ValueError
        Not a two-dimensional array, no sample, or a magnitude above :data:`MAX_MAGNITUDE`.
    """
    values = np.asarray(q, dtype=np.int64)
    if values.ndim != 2 or values.shape[0] < 1:
        raise ValueError(f"fit_prior_codes needs an (n ≥ 1, D) array of integers, got shape {values.shape}")
    candidates = range(-PRIOR_CODE_LIMIT, PRIOR_CODE_LIMIT + 1)
    fitted = []
    for column in values.T:
        lengths = [ideal_code_bits(column, np.full(len(column), c, dtype=np.int64)) for c in candidates]
        fitted.append(candidates[int(np.argmin(lengths))])  # argmin: the first of equal lengths, the narrowest
    return np.asarray(fitted, dtype=np.int64)


def coded_prefix_sizes(q: npt.ArrayLike, codes: npt.ArrayLike) -> list[int]:
    """``len(encode_integers(q[:k], codes[:k]))`` for every k = 0 … len(q), in one pass of the coder.

    Raises
    ------
    ValueError
        As :func:`encode_integers`.
    """
    sizes: list[int] = []
    _code(*_checked(q, codes), prefix_sizes=sizes)
    return sizes


class _BoolDecoder:
    """RFC 6386 §7.3's boolean decoder; bytes past the end read as 0."""

    def __init__(self, data: bytes) -> None:
        self.data, self.position = data, 2
        self.value = (self._byte(0) << 8) | self._byte(1)
        self.span, self.bit_count = 255, 0

    def _byte(self, i: int) -> int:
        return self.data[i] if i < len(self.data) else 0

    def read(self, probability: int) -> int:
        split = 1 + (((self.span - 1) * probability) >> 8)
        big_split = split << 8
        if self.value >= big_split:
            bit, self.span, self.value = 1, self.span - split, self.value - big_split
        else:
            bit, self.span = 0, split
        while self.span < 128:
            self.value <<= 1
            self.span <<= 1
            self.bit_count += 1
            if self.bit_count == 8:
                self.bit_count = 0
                self.value |= self._byte(self.position)
                self.position += 1
        return bit


def decode_integers(data: bytes, codes: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Inverse of :func:`encode_integers`: one integer per prior code.

    Raises
    ------
    ValueError
        An escape prefix longer than :data:`MAX_ESCAPE_PREFIX` ones (malformed bytes).
    """
    prior = np.asarray(codes, dtype=np.int64).reshape(-1)
    reader = _BoolDecoder(bytes(data))
    out = np.zeros(len(prior), dtype=np.int64)
    for i, code in enumerate(prior.tolist()):
        if not reader.read(ZERO_PROBABILITY[code + PRIOR_CODE_LIMIT]):
            continue
        negative = reader.read(128)
        stop = STOP_PROBABILITY[code + PRIOR_CODE_LIMIT]
        m = 1
        while m <= _UNARY and reader.read(stop):
            m += 1
        if m > _UNARY:
            prefix = 0
            while reader.read(128):
                prefix += 1
                if prefix > MAX_ESCAPE_PREFIX:
                    raise ValueError(f"a coded basis layer escapes with more than {MAX_ESCAPE_PREFIX} prefix bits")
            rest = 1
            for _ in range(prefix):
                rest = (rest << 1) | reader.read(128)
            m = _UNARY + rest
        out[i] = -m if negative else m
    return out


class CodedChoice:
    """A coded layer chosen for some coefficients: step code, integers and their coder bytes.

    Attributes
    ----------
    step_code : int
    q : ndarray of int64, shape (k,)
    data : bytes
        The coder's bytes (without the step code).
    error : float
        Squared error in coefficient space: the kept coefficients' rounding plus the dropped ones.
    """

    __slots__ = ("data", "error", "q", "step_code")

    def __init__(self, step_code: int, q: npt.NDArray[np.int64], data: bytes, error: float) -> None:
        self.step_code, self.q, self.data, self.error = step_code, q, data, error


#: Rounding offsets tried by :func:`choose_coding`: q = sign(c)·⌊|c|/s + θ⌋; below ½ a dead zone (more zeros and
#: smaller magnitudes, fewer bits, so a finer step fits the same bytes).
ROUNDING_OFFSETS: Final = (0.5, 0.4, 0.3)


def _quantise(c: npt.NDArray[np.float64], s: float, offset: float) -> npt.NDArray[np.int64]:
    q = np.sign(c) * np.floor(np.abs(c) / s + offset)
    return np.clip(q, -MAX_MAGNITUDE, MAX_MAGNITUDE).astype(np.int64)


def choose_coding(coefficients: npt.ArrayLike, first: int, max_bytes: int, amplitude: int, decay: int,
                  *, count: int | None = None, lead: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
                  ) -> CodedChoice | None:
    """The coded layer of at most ``max_bytes`` (step code included) closest to the coefficients.

    For each rounding offset of :data:`ROUNDING_OFFSETS`, finds by bisection the finest step code whose integers
    (up to the last non-zero one) fit, then tries the 12 step codes around it, each keeping the most leading
    integers that fit; measures the squared error of the kept coefficients' rounding plus the dropped ones'
    energy (the basis is orthonormal: the squared error of the layer's sum) and returns the lowest — the step,
    rounding and count that minimise distortion at this rate. None when not even one coefficient fits.

    Parameters
    ----------
    coefficients : array_like, shape (K,)
        Coefficients of vectors ``first``, ``first + 1``, … (mapped units).
    first : int
    max_bytes : int
    amplitude, decay : int
        The form's prior (0 … 255 each).
    count : int, optional
        Keep at most this many coefficients.
    lead : (array_like of int, array_like of int), optional
        Integers and their prior codes coded ahead of the coefficients in the same stream (a coded μ, format
        2.5, ``spec/bvae-format.md`` §4.9): they take their bytes first, and ``data`` holds them too.
    """
    c = np.asarray(coefficients, dtype=np.float64).reshape(-1)
    lead_q, lead_codes = _checked(*(lead if lead is not None else ((), ())))
    if not np.isfinite(c).all():
        raise ValueError("basis coefficients must be finite")
    if count is not None:
        c = c[: int(count)]
    budget = int(max_bytes) - CODED_HEADER_BYTES
    if budget < 0 or not len(c):
        return None
    energy_after = np.concatenate([np.cumsum((c ** 2)[::-1])[::-1], [0.0]])
    codes_of = functools.cache(lambda e: prior_codes(amplitude, decay, e, first, len(c)))  # per step code
    best: CodedChoice | None = None

    def stream(q: npt.NDArray[np.int64], e: int, k: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        return np.concatenate([lead_q, q[:k]]), np.concatenate([lead_codes, codes_of(e)[:k]])

    def size(q: npt.NDArray[np.int64], e: int) -> int:
        nonzero = np.flatnonzero(q)
        k = int(nonzero[-1]) + 1 if len(nonzero) else 0
        return len(encode_integers(*stream(q, e, k)))

    for offset in ROUNDING_OFFSETS:
        lo, hi = 0, 255  # bisect the finest step code whose whole layer fits (sizes fall as the step grows)
        if size(_quantise(c, packed_step(hi), offset), hi) > budget:
            continue
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if size(_quantise(c, packed_step(mid), offset), mid) <= budget:
                hi = mid
            else:
                lo = mid
        for e in range(max(0, hi - 8), min(256, hi + 4)):
            s = packed_step(e)
            q = _quantise(c, s, offset)
            nonzero = np.flatnonzero(q)
            k = int(nonzero[-1]) + 1 if len(nonzero) else 0
            sizes = coded_prefix_sizes(*stream(q, e, k))[len(lead_q):]  # sizes[j]: the lead and j coefficients
            if sizes[k] > budget:  # fewer coefficients: bisect the most that fit (on every prefix's size)
                low, high = 0, k
                while high - low > 1:
                    mid = (low + high) // 2
                    if sizes[mid] <= budget:
                        low = mid
                    else:
                        high = mid
                k = low
            if k == 0:
                continue
            error = float(((c[:k] - q[:k] * s) ** 2).sum() + energy_after[k])
            if best is None or error < best.error:
                best = CodedChoice(e, q[:k].copy(), encode_integers(*stream(q, e, k)), error)
    return best
