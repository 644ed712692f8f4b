"""Packed basis coefficients: one step, fewer bits for later vectors (``spec/bvae-format.md`` §4.7, format 2.3).

A basis layer stored as int8 spends 8 bits on every coefficient, although a
shared basis' later vectors carry smaller coefficients than its first ones
(the basis is ordered by variance, which falls roughly as a power of the
vector's rank). A *packed* layer quantises every coefficient with one step s
and gives coefficient i of vector n = f + i + 1 (f the layer's first vector)
a two's-complement field of

    bᵢ = T − round(log₂ n)   bits,

where T, the *top width*, is stated once per record form. At the same step
the later coefficients then cost a few bits each instead of eight, so a size
budget holds more of them.

Part of :mod:`brdfcodec.layers.basis`, which gathers the names of its parts.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

__all__ = [
    "MAX_TOP_WIDTH",
    "PACKED_HEADER_BYTES",
    "PackedChoice",
    "choose_packing",
    "pack_fields",
    "packed_bytes",
    "packed_step",
    "packed_step_code",
    "packed_widths",
    "unpack_fields",
]

#: Largest top width T (bits of a coefficient of vector 1).
MAX_TOP_WIDTH: Final = 24

#: Bytes of a packed layer before its fields: the step code.
PACKED_HEADER_BYTES: Final = 1

#: The step code e gives s = 2^(e / 16 − 8): 2⁻⁸ (0.0039) to 2^7.94 (245) in steps of 4.4 %.
_STEP_CODES: Final = 256
_STEP_PER_OCTAVE: Final = 16
_STEP_OFFSET: Final = 8


def packed_step(code: int) -> float:
    """The step s = 2^(code / 16 − 8) of step code 0 … 255, computed in binary64 and rounded once to binary32."""
    if isinstance(code, bool) or not isinstance(code, int | np.integer) or not 0 <= code < _STEP_CODES:
        raise ValueError(f"packed step code must be an integer in [0, {_STEP_CODES - 1}], got {code!r}")
    return float(np.float32(2.0 ** (int(code) / _STEP_PER_OCTAVE - _STEP_OFFSET)))


def packed_step_code(step: float) -> int:
    """The step code whose step is ``step`` exactly.

    Raises
    ------
    ValueError
        ``step`` is not one of the 256 packed steps.
    """
    value = float(step)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"packed step must be a positive finite number, got {step!r}")
    code = int(round((np.log2(value) + _STEP_OFFSET) * _STEP_PER_OCTAVE))
    if not 0 <= code < _STEP_CODES or packed_step(code) != value:
        raise ValueError(f"packed step {step!r} is not 2^(e/16 − 8) for an integer e in [0, 255]")
    return code


def _round_log2(n: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """round(log₂ n) for integers n ≥ 1, exactly: ⌊log₂(2n²) / 2⌋ (log₂ n is never halfway between integers),
    in Python integers."""
    return np.array([((2 * v * v).bit_length() - 1) // 2 for v in n.tolist()], dtype=np.int64)


def packed_widths(top: int, first: int, count: int) -> npt.NDArray[np.int64]:
    """Bits bᵢ = T − round(log₂(f + i + 1)) of coefficients i = 0 … k − 1 (may be 0 or negative past the last
    coefficient a layer can hold; a layer holds only coefficients of width ≥ 1)."""
    n = np.arange(first + 1, first + count + 1, dtype=np.int64)
    return int(top) - _round_log2(n)


def packed_bytes(top: int, first: int, count: int) -> int:
    """Stored size of a packed layer: the step code and ⌈Σ bᵢ / 8⌉ bytes of fields."""
    return PACKED_HEADER_BYTES + (int(packed_widths(top, first, count).sum()) + 7) // 8


def pack_fields(q: npt.ArrayLike, widths: npt.ArrayLike) -> bytes:
    """Integers as consecutive two's-complement fields of the given widths, least significant bit first, in a
    bit stream whose bit j is bit j mod 8 of byte ⌊j / 8⌋; the last byte's unused bits are 0.

    Raises
    ------
    ValueError
        A width is below 1, or a value does not fit its field (−2^(b−1) … 2^(b−1) − 1).
    """
    values = np.asarray(q, dtype=np.int64).reshape(-1)
    bits = np.asarray(widths, dtype=np.int64).reshape(-1)
    if values.shape != bits.shape:
        raise ValueError(f"{len(values)} values for {len(bits)} widths")
    if (bits < 1).any() or (bits > 63).any():
        raise ValueError("packed field widths must be 1 to 63 bits")
    low, high = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    if ((values < low) | (values > high)).any():
        raise ValueError("a packed value does not fit its field")
    stream = []
    for value, width in zip(values.tolist(), bits.tolist(), strict=True):
        unsigned = value & ((1 << width) - 1)
        stream.extend((unsigned >> b) & 1 for b in range(width))
    return np.packbits(np.array(stream, dtype=np.uint8), bitorder="little").tobytes()


def unpack_fields(data: bytes, widths: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Inverse of :func:`pack_fields`.

    Raises
    ------
    ValueError
        The bytes are not exactly ⌈Σ b / 8⌉ long, or an unused bit of the last byte is set.
    """
    bits = np.asarray(widths, dtype=np.int64).reshape(-1)
    total = int(bits.sum())
    if len(data) != (total + 7) // 8:
        raise ValueError(f"packed fields take {(total + 7) // 8} bytes, got {len(data)}")
    stream = np.unpackbits(np.frombuffer(data, dtype=np.uint8), bitorder="little").astype(np.int64)
    if stream[total:].any():
        raise ValueError("a packed layer's unused bits must be 0")
    out = np.empty(len(bits), dtype=np.int64)
    position = 0
    for i, width in enumerate(bits.tolist()):
        field = stream[position:position + width]
        unsigned = int((field << np.arange(width, dtype=np.int64)).sum())
        out[i] = unsigned - (1 << width) if unsigned >> (width - 1) else unsigned
        position += width
    return out


class PackedChoice:
    """A packed layer chosen for some coefficients: step code, top width and the fields' values.

    Attributes
    ----------
    step_code : int
    top : int
    q : ndarray of int64, shape (k,)
    error : float
        Squared error in coefficient space: of the kept coefficients' rounding plus the dropped ones.
    """

    __slots__ = ("error", "q", "step_code", "top")

    def __init__(self, step_code: int, top: int, q: npt.NDArray[np.int64], error: float) -> None:
        self.step_code, self.top, self.q, self.error = step_code, top, q, error


def choose_packing(coefficients: npt.ArrayLike, first: int, max_bytes: int) -> PackedChoice | None:
    """The packed layer of at most ``max_bytes`` (step code included) closest to the coefficients.

    Tries every top width and every step code; for each, keeps as many leading coefficients as fit (each of
    width ≥ 1), rounds them to the step (clipped to their fields) and measures the squared error of the kept
    coefficients' rounding plus the dropped coefficients' energy (the basis is orthonormal, so this is the
    squared error of the layer's sum). Returns the lowest, or None when not even one coefficient fits.

    Parameters
    ----------
    coefficients : array_like, shape (K,)
        Coefficients of vectors ``first``, ``first + 1``, … (mapped units).
    first : int
        Index f of the first coefficient's vector.
    max_bytes : int
        Largest layer size in bytes.
    """
    c = np.asarray(coefficients, dtype=np.float64).reshape(-1)
    if not np.isfinite(c).all():
        raise ValueError("basis coefficients must be finite")
    bit_budget = 8 * (int(max_bytes) - PACKED_HEADER_BYTES)
    if bit_budget < 1 or not len(c):
        return None
    energy_after = np.concatenate([np.cumsum((c ** 2)[::-1])[::-1], [0.0]])
    steps = np.array([packed_step(e) for e in range(_STEP_CODES)])
    best: PackedChoice | None = None
    for top in range(1, MAX_TOP_WIDTH + 1):
        widths = packed_widths(top, first, len(c))
        usable = int(np.argmax(widths < 1)) if (widths < 1).any() else len(widths)
        cumulative = np.cumsum(widths[:usable])
        k = int(np.searchsorted(cumulative, bit_budget, side="right"))
        if k == 0:
            continue
        b = widths[:k]
        low, high = -(2.0 ** (b - 1)), 2.0 ** (b - 1) - 1
        q = np.clip(np.rint(c[None, :k] / steps[:, None]), low, high)
        errors = ((c[None, :k] - q * steps[:, None]) ** 2).sum(axis=1) + energy_after[k]
        code = int(np.argmin(errors))
        if best is None or errors[code] < best.error:
            best = PackedChoice(code, top, q[code].astype(np.int64), float(errors[code]))
    return best
