"""The basis layer's numbers: its limits, and int8 values with a step (``spec/bvae-format.md`` §3.3).

Part of :mod:`brdfcodec.layers.basis`, which gathers the names of its parts.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import NETWORK_INPUT_SHAPE

__all__ = [
    "BASIS_FILE",
    "FIXED_MU_LIMIT",
    "FIXED_MU_STEP",
    "MAX_BASIS_COUNT",
    "dequantise_int8",
    "fits_fixed_mu_grid",
    "int8_from_step_bytes",
    "int8_on_fixed_grid",
    "int8_step_bytes",
    "int8_with_step",
]


#: File name of a model's shared basis, beside ``decoder.safetensors``.
BASIS_FILE: Final = "basis.safetensors"

#: Most coefficients a record may carry (and most vectors a basis may hold).
MAX_BASIS_COUNT: Final = 4096

_ENTRIES_PER_CHANNEL: Final = NETWORK_INPUT_SHAPE[1] * NETWORK_INPUT_SHAPE[2]

_N_ENTRIES: Final = int(np.prod(NETWORK_INPUT_SHAPE))

#: Bytes of the step that precedes the coefficients.
STEP_BYTES: Final = 2

#: Columns of the factors summed at a time (a block of 64 float32 factors is 512 kB: it stays in cache while
#: the three colours read it).
_COLUMN_BLOCK: Final = 2048

def int8_with_step(values: npt.ArrayLike, what: str = "values") -> tuple[float, npt.NDArray[np.int8]]:
    """Values quantised to int8 with one float16 step: ``(s, q)`` with s = max |v| / 127 (rounded up to a
    float16 value, at least 1e-4) and q = round(v / s) in −127…127, so every value is kept within s / 2.

    Used by the basis layer's coefficients and by a layered record's compact μ (``spec/bvae-format.md`` §4.5).

    Raises
    ------
    ValueError
        A value is not finite, or so large that the step would leave the float16 range.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if not np.isfinite(v).all():
        raise ValueError(f"{what} must be finite")
    largest = float(np.abs(v).max(initial=0.0))
    if largest > 127.0 * 60000.0:
        raise ValueError(f"{what} reach {largest:.4g}, too large for an int8 code with a float16 step")
    step = np.float16(max(largest / 127.0, 1e-4))
    if largest / float(step) > 127.49:  # float16 rounding made the step too small for the largest value
        step = np.nextafter(step, np.float16(np.inf))
    q = np.clip(np.rint(v / float(step)), -127, 127).astype(np.int8)
    return float(step), q

#: Step of a compact μ on the fixed grid (``layers.mu = "int8-fixed"``, ``spec/bvae-format.md`` §4.5): μ = q / 32.
FIXED_MU_STEP: Final = 1.0 / 32.0

#: Largest |μ| the fixed grid holds: 127 steps (−127 … 127, the same range as :func:`int8_with_step`).
FIXED_MU_LIMIT: Final = 127.0 * FIXED_MU_STEP

def fits_fixed_mu_grid(values: npt.ArrayLike) -> bool:
    """Whether every value is finite and within ±:data:`FIXED_MU_LIMIT` (3.97), the fixed μ grid's range."""
    v = np.asarray(values, dtype=np.float64)
    return bool(np.isfinite(v).all() and (np.abs(v) <= FIXED_MU_LIMIT).all())

def int8_on_fixed_grid(values: npt.ArrayLike, what: str = "values") -> npt.NDArray[np.int8]:
    """Values as int8 codes on the fixed μ grid: q = round(32 · v), clipped to −127…127 (so a value past
    ±3.97 is stored as the grid's end; an encoder fits the layers to the stored code).

    Raises
    ------
    ValueError
        A value is not finite.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if not np.isfinite(v).all():
        raise ValueError(f"{what} must be finite")
    return np.clip(np.rint(v / FIXED_MU_STEP), -127, 127).astype(np.int8)

def dequantise_int8(step: float, q: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """``s · q`` in float32: the values an int8 code with a float16 step stands for."""
    return np.float32(step) * np.asarray(q).astype(np.float32)

def int8_step_bytes(step: float, q: npt.NDArray[np.int8]) -> bytes:
    """The stored form of an int8 code: the step as a little-endian float16, then the int8 values."""
    return np.float16(step).astype("<f2").tobytes() + np.asarray(q, dtype=np.int8).tobytes()

def int8_from_step_bytes(data: bytes, what: str) -> tuple[float, npt.NDArray[np.int8]]:
    """Inverse of :func:`int8_step_bytes`: ``(s, q)``, refused unless s is a positive finite number.

    Raises
    ------
    ValueError
        The step is zero, negative, infinite or NaN (``what`` names it in the message).
    """
    step = float(np.frombuffer(data[:STEP_BYTES], dtype="<f2")[0])
    if not (np.isfinite(step) and step > 0):
        raise ValueError(f"{what} {step} is not a positive finite number")
    return step, np.frombuffer(data[STEP_BYTES:], dtype=np.int8).copy()
