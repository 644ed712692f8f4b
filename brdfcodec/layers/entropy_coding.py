"""Entropy coding of integer vectors under per-entry quantised Laplace (or Gaussian) priors.

A transform coder quantises coefficients to integers ``qᵢ = round(cᵢ/Δ)``;
their distribution is known ahead from training (each coefficient's spread).
This module codes such a vector **for real** with the range coder of
`constriction <https://bamler-lab.github.io/constriction/>`_, entry ``i``
under a zero-mean Laplace (or Gaussian) density of standard deviation
``spreads[i]`` (in quantiser bins) integrated over the bin
``[q − ½, q + ½]`` on the symbols ``−boundᵢ … boundᵢ`` (constriction's
``QuantizedLaplace`` / ``QuantizedGaussian``: every symbol in range keeps a
non-zero probability, so any vector within the bounds can be coded). The
bound is one for all entries or one per entry: each symbol in range keeps at
least 2⁻²⁴ of the probability, so a bound near the entry's plausible range
(a few spreads) costs less than one far beyond it.

- :func:`encode_integers` returns the coder's bytes, **terminated as short as
  the decoder allows**: the range coder's 32-bit words are written
  big-endian, then the shortest byte string (a prefix of them, or that prefix
  plus one in its last place) that :func:`decode_integers` turns back into the
  same vector is kept — checked by decoding, so the round trip is exact by
  construction. Its length is within about one byte of the ideal code length
  (:func:`ideal_code_length_bits`), termination included.
- :func:`decode_integers` appends zero bytes (to whole words, then two more
  words) and decodes.

Both are deterministic: the same symbols, spreads and bound give the same
bytes. The priors' bin probabilities are computed by constriction in 64-bit
floating point and rounded to its fixed-point precision; encoder and decoder
must run the same constriction release (the format pins it where it stores
such bytes). A range coder detects only some corruptions: damaged bytes may
decode to a wrong vector without an error, so a container checks its bytes
(a CRC) before decoding them.

Units: symbols are integers (quantiser bins), spreads are standard
deviations in bins, lengths are bytes (:func:`encode_integers`) or bits
(:func:`ideal_code_length_bits`).

>>> import numpy as np
>>> q = np.array([3, -1, 0, 0, 1])
>>> spreads = np.array([4.0, 2.0, 1.0, 0.5, 0.25])
>>> data = encode_integers(q, spreads, bound=255)
>>> decode_integers(data, spreads, bound=255).tolist()
[3, -1, 0, 0, 1]
>>> len(data), round(ideal_code_length_bits(q, spreads, bound=255) / 8, 2)
(2, 1.62)
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.errors import FileFormatError

__all__ = ["MAX_BOUND", "Prior", "decode_integers", "encode_integers", "ideal_code_length_bits"]

#: The priors this module codes with.
Prior = Literal["laplace", "gaussian"]

#: The largest ``bound`` accepted: symbols lie in ``[−bound, bound]``.
MAX_BOUND = 2**20

#: Zero words the decoder appends beyond the data (the coder's state is two 32-bit words).
_PAD_WORDS = 2


def _check(spreads: npt.ArrayLike, bound: int | npt.ArrayLike,
           prior: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Spreads and per-entry bounds as arrays, after checking them."""
    s = np.asarray(spreads, dtype=np.float64)
    if s.ndim != 1:
        raise ValueError(f"spreads must be a 1-D array, got shape {s.shape}")
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError("spreads must be finite and > 0 (standard deviations in quantiser bins)")
    given = np.asarray(bound)
    if given.ndim not in (0, 1) or (given.ndim == 1 and given.shape != s.shape):
        raise ValueError(f"bound must be a whole number or one per entry (shape {s.shape}), got shape {given.shape}")
    if given.dtype.kind not in "iuf" or not np.all(np.isfinite(given)) or np.any(given != np.rint(given)) or (
            given.size and (given.min() < 1 or given.max() > MAX_BOUND)):
        raise ValueError(f"bound must hold whole numbers in [1, {MAX_BOUND}], got {bound!r}")
    if prior not in ("laplace", "gaussian"):
        raise ValueError(f"prior must be 'laplace' or 'gaussian', got {prior!r}")
    return s, np.broadcast_to(given.astype(np.int64), s.shape)


def _symbols(symbols: npt.ArrayLike, bounds: npt.NDArray[np.int64]) -> npt.NDArray[np.int32]:
    q = np.asarray(symbols)
    if q.shape != bounds.shape:
        raise ValueError(f"symbols have shape {q.shape}, spreads {bounds.shape}")
    if q.size and not np.issubdtype(q.dtype, np.integer):
        if not np.all(np.isfinite(q)) or np.any(q != np.rint(q)):
            raise ValueError("symbols must be integers")
    if q.size and np.any(np.abs(q) > bounds):
        i = int(np.argmax(np.abs(q) > bounds))
        raise ValueError(f"symbol {i} lies outside [−{bounds[i]}, {bounds[i]}]: {int(q[i])}")
    return q.astype(np.int32)


def _groups(bounds: npt.NDArray[np.int64]) -> list[tuple[int, npt.NDArray[np.intp]]]:
    """Entries coded under one model family, in coding order: by increasing bound, entries in order."""
    if len(bounds) == 0:
        return []
    order = np.argsort(bounds, kind="stable")
    values, starts = np.unique(bounds[order], return_index=True)
    return [(int(b), order[start:end]) for b, start, end in zip(values, starts, [*starts[1:], len(order)],
                                                                 strict=True)]


def _family(bound: int, prior: str) -> Any:
    import constriction

    if prior == "laplace":
        return constriction.stream.model.QuantizedLaplace(-bound, bound)
    return constriction.stream.model.QuantizedGaussian(-bound, bound)


def _widths(spreads: npt.NDArray[np.float64], prior: str) -> npt.NDArray[np.float64]:
    # The Laplace scale b has variance 2b²; the Gaussian's parameter is its standard deviation.
    width = spreads / math.sqrt(2.0) if prior == "laplace" else spreads
    return np.ascontiguousarray(width, dtype=np.float64)


def _decode(data: bytes, widths: npt.NDArray[np.float64], groups: list[tuple[int, npt.NDArray[np.intp]]],
            prior: str) -> npt.NDArray[np.int64] | None:
    """The vector coded in ``data`` (prior widths, groups of :func:`_groups`), or None where the coder finds
    the data invalid for the priors."""
    import constriction

    result = np.zeros(len(widths), dtype=np.int64)
    if len(widths) == 0:
        return result
    padded = bytes(data) + b"\0" * ((-len(data)) % 4 + 4 * _PAD_WORDS)
    words = np.frombuffer(padded, dtype=">u4").astype(np.uint32)
    decoder = constriction.stream.queue.RangeDecoder(words)
    try:
        for bound, entries in groups:
            result[entries] = decoder.decode(_family(bound, prior), np.zeros(len(entries)), widths[entries])
    except (AssertionError, ValueError, RuntimeError):
        return None
    return result


def encode_integers(symbols: npt.ArrayLike, spreads: npt.ArrayLike, *, bound: int,
                    prior: Prior = "laplace") -> bytes:
    """Range-code an integer vector under per-entry quantised priors, terminated as short as decoding allows.

    Parameters
    ----------
    symbols : array_like of int, shape (n,)
        The integers to code, each in ``[−bound, bound]`` (quantiser bins).
    spreads : array_like of float, shape (n,)
        Standard deviation of each entry's zero-mean prior before quantisation, > 0 (quantiser bins).
    bound : int or array_like of int, shape (n,)
        Symbols lie in ``[−bound, bound]`` (one bound for all entries, or one per entry), each in
        ``[1,`` :data:`MAX_BOUND` ``]``; the decoder needs the same. Entries of one bound are coded together,
        by increasing bound.
    prior : {"laplace", "gaussian"}, optional
        The density quantised to the bins (default Laplace).

    Returns
    -------
    bytes
        The coded vector; ``b""`` for an empty one. :func:`decode_integers` with the same spreads, bound and
        prior returns ``symbols``.

    Raises
    ------
    ValueError
        Shapes that differ, non-integer symbols or symbols beyond their bound, spreads not finite and > 0, a
        bound outside ``[1, MAX_BOUND]`` or of another shape, an unknown prior.
    """
    import constriction

    s, bounds = _check(spreads, bound, prior)
    q = _symbols(symbols, bounds)
    if len(q) == 0:
        return b""
    encoder = constriction.stream.queue.RangeEncoder()
    widths = _widths(s, prior)
    groups = _groups(bounds)
    for group_bound, entries in groups:
        encoder.encode(q[entries], _family(group_bound, prior), np.zeros(len(entries)), widths[entries])
    full = np.asarray(encoder.get_compressed(), dtype=np.uint32).astype(">u4").tobytes()
    expected = q.astype(np.int64)

    def decodes(candidate: bytes) -> bool:
        result = _decode(candidate, widths, groups, prior)
        return result is not None and np.array_equal(result, expected)

    # The shortest termination: drop trailing bytes while a prefix (or the prefix plus one in its last byte,
    # which rounds the code point up into the final interval) still decodes to the same vector.
    best = full
    for length in range(len(full) - 1, -1, -1):
        prefix = full[:length]
        candidates = [prefix]
        if length:
            value = int.from_bytes(prefix, "big") + 1
            if value < 256**length:
                candidates.append(value.to_bytes(length, "big"))
        found = next((c for c in candidates if decodes(c)), None)
        if found is None:
            break
        best = found
    if not decodes(best):  # the coder's own output always decodes; this guards the termination search
        raise RuntimeError("entropy coder round trip failed")  # pragma: no cover
    return best


def decode_integers(data: bytes, spreads: npt.ArrayLike, *, bound: int,
                    prior: Prior = "laplace") -> npt.NDArray[np.int64]:
    """Decode an integer vector written by :func:`encode_integers`.

    Parameters
    ----------
    data : bytes
        The coded vector.
    spreads : array_like of float, shape (n,)
        The spreads it was coded with (quantiser bins); ``n`` is the vector's length.
    bound : int or array_like of int, shape (n,)
        The bound(s) it was coded with.
    prior : {"laplace", "gaussian"}, optional
        The prior it was coded with.

    Returns
    -------
    ndarray of int64, shape (n,)
        The symbols, each in ``[−bound, bound]``.

    Raises
    ------
    ValueError
        Spreads, bound or prior as :func:`encode_integers` refuses them.
    FileFormatError
        The coder finds the data invalid for these priors (damaged or not such data). Damage is not always
        detected: check the bytes (a CRC) before decoding.
    """
    s, bounds = _check(spreads, bound, prior)
    result = _decode(bytes(data), _widths(s, prior), _groups(bounds), prior)
    if result is None:
        raise FileFormatError(f"entropy-coded integers: {len(data)} bytes are not a valid code of {len(s)} "
                              f"symbols under these {prior} priors")
    return result


def ideal_code_length_bits(symbols: npt.ArrayLike, spreads: npt.ArrayLike, *, bound: int,
                           prior: Prior = "laplace") -> float:
    """The ideal code length ``−Σ log₂ pᵢ(qᵢ)`` of a vector under the quantised priors (bits).

    The prior of each entry is the density integrated over ``[q − ½, q + ½]``, the tails beyond the bound
    folded into the end bins. :func:`encode_integers` writes within about one byte of it (its fixed-point
    rounding and the termination); use this for rate estimates, the coder for counted bytes.

    Parameters
    ----------
    symbols, spreads, bound, prior
        As for :func:`encode_integers`.

    Returns
    -------
    float
        Bits, ≥ 0.

    Raises
    ------
    ValueError
        As :func:`encode_integers`.
    """
    s, bounds = _check(spreads, bound, prior)
    q = _symbols(symbols, bounds).astype(np.float64)
    upper = np.where(q >= bounds, np.inf, q + 0.5)
    lower = np.where(q <= -bounds, -np.inf, q - 0.5)
    if prior == "laplace":
        b = s / math.sqrt(2.0)

        def tail(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:  # P(X > x) for x ≥ 0
            return 0.5 * np.exp(-x / b)

        # Probability of [lower, upper] by symmetry: bins on one side from the tails, the central bin from 1.
        hi = np.abs(upper)
        lo = np.abs(lower)
        p = np.where(q == 0, 1.0 - tail(hi) - tail(lo),
                     np.abs(tail(np.minimum(lo, hi)) - tail(np.maximum(lo, hi))))
    else:
        erfc = np.vectorize(math.erfc, otypes=[np.float64])

        def tail(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
            return 0.5 * erfc(x / (s * math.sqrt(2.0)))

        hi = np.abs(upper)
        lo = np.abs(lower)
        p = np.where(q == 0, 1.0 - tail(hi) - tail(lo),
                     np.abs(tail(np.minimum(lo, hi)) - tail(np.maximum(lo, hi))))
    return float(-np.sum(np.log2(np.maximum(p, np.finfo(np.float64).tiny))))
