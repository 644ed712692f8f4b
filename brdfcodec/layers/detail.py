"""The detail layer: a per-material, transform-coded residual of the kept slices (``spec/bvae-format.md`` §4.4).

The residual ``r = x − D(μ)`` (mapped domain, network layout ``(63, 90, 90)``,
entries below the horizon set to 0) is coded as:

1. colour decorrelation with the orthonormal matrix :data:`COLOUR_MATRIX`
   (a luma-like sum and two differences) over the 3 colour blocks;
2. an orthonormal DCT-II along the kept-slice axis (21), θh (90) and θd (90);
3. uniform scalar quantisation with step ``Δ``: ``q = round(c / Δ)``;
4. the integers in that (colour, slice frequency, θh frequency, θd
   frequency) C order, as little-endian int16 (int32 when some
   |q| > 32767), packed as one zstandard frame. (Reordering by total
   frequency was measured and packs worse at fine steps.)

Every step is orthonormal, so the mean squared error added to the mapped
kept slices is at most ``Δ² / 12`` per entry. Decoding is the exact inverse
of steps 4 to 1; the slice axis is inverted only for the kept slices asked
for, so partial decoding (``phi_d_bins``) does not pay for the others.

This module does not import torch.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_CHANNELS, N_KEPT_SLICES, NETWORK_INPUT_SHAPE

__all__ = [
    "COLOUR_MATRIX",
    "DETAIL_TRANSFORM",
    "DetailLayer",
    "check_detail_frame",
    "decode_detail",
    "encode_detail",
]

#: Name of the transform stored in a file (``layers.detail.transform``).
DETAIL_TRANSFORM = "dct3-ycc"
#: Rows: the orthonormal colour transform applied to the (R, G, B) blocks.
COLOUR_MATRIX = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, 0.0], [1.0, 1.0, -2.0]])
COLOUR_MATRIX /= np.linalg.norm(COLOUR_MATRIX, axis=1, keepdims=True)
COLOUR_MATRIX.setflags(write=False)

_SHAPE = (N_CHANNELS, N_KEPT_SLICES, *NETWORK_INPUT_SHAPE[1:])  # (3, 21, 90, 90)
#: Number of integers a detail layer holds (63·90·90).
N_DETAIL_VALUES = int(np.prod(_SHAPE))
_DTYPES = {"int16": np.dtype("<i2"), "int32": np.dtype("<i4")}
_ZSTD_LEVEL = 19
#: Largest zstandard window a detail frame may ask a reader for (its content is at most 2 MB).
_MAX_WINDOW: Final = 1 << 22
#: Smallest and largest quantisation step a file may declare (mapped units).
MIN_STEP, MAX_STEP = 1e-5, 100.0
#: A plane-by-plane inverse is taken when its multiply-adds are at most this share of the batched inverse's
#: (the loop costs more per multiply-add, so it pays only where it skips enough of them).
_DENSE_SHARE: Final = 0.5


@functools.cache
def _dct_matrix(n: int) -> np.ndarray:
    """Orthonormal DCT-II matrix, ``(n, n)``: row f is frequency f."""
    k = np.arange(n)
    matrix = np.cos(np.pi * (2 * k[None, :] + 1) * k[:, None] / (2 * n)) * np.sqrt(2.0 / n)
    matrix[0] /= np.sqrt(2.0)
    matrix.setflags(write=False)
    return matrix


@dataclass(frozen=True)
class DetailLayer:
    """A coded residual: the quantisation step, the integer type and the zstandard frame.

    Attributes
    ----------
    step : float
        Quantisation step Δ in mapped units, in [1e-5, 100].
    dtype : {"int16", "int32"}
        Storage of the integers before packing.
    data : bytes
        One zstandard frame that declares its content size
        (``63·90·90 · itemsize`` bytes).
    """

    step: float
    dtype: str
    data: bytes

    def __post_init__(self) -> None:
        if not (isinstance(self.step, float) and MIN_STEP <= self.step <= MAX_STEP):
            raise ValueError(f"detail step must be a float in [{MIN_STEP}, {MAX_STEP}], got {self.step!r}")
        if self.dtype not in _DTYPES:
            raise ValueError(f"detail dtype must be one of {sorted(_DTYPES)}, got {self.dtype!r}")
        if not isinstance(self.data, bytes) or not self.data:
            raise ValueError("detail data must be non-empty bytes")

    @property
    def nbytes(self) -> int:
        """Stored size of the layer's payload, in bytes."""
        return len(self.data)

    def entry(self) -> dict[str, object]:
        """The ``layers.detail`` object of the record's index entry."""
        return {"transform": DETAIL_TRANSFORM, "step": self.step, "dtype": self.dtype, "length": len(self.data)}


def encode_detail(residual: npt.ArrayLike, step: float) -> DetailLayer:
    """Code a mapped residual at quantisation step ``step``.

    Parameters
    ----------
    residual : array_like, shape (63, 90, 90)
        Target minus base decode, mapped units, network layout; entries below
        the horizon should be 0.
    step : float
        Quantisation step Δ (mapped units): larger is smaller and coarser.

    Returns
    -------
    DetailLayer
    """
    import zstandard

    array = np.asarray(residual, dtype=np.float64)
    if array.shape != NETWORK_INPUT_SHAPE:
        raise ValueError(f"residual must have shape {NETWORK_INPUT_SHAPE}, got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError("residual must be finite")
    step = float(step)
    DetailLayer(step, "int16", b"\0")  # validates the step
    coefficients = _forward(array.reshape(_SHAPE))
    q = np.rint(coefficients.reshape(-1) / step)
    dtype = "int16" if np.abs(q).max(initial=0) <= 32767 else "int32"
    if np.abs(q).max(initial=0) > 2**31 - 1:
        raise ValueError(f"detail step {step} is too fine for this residual")
    raw = q.astype(_DTYPES[dtype]).tobytes()
    data = zstandard.ZstdCompressor(level=_ZSTD_LEVEL, write_content_size=True).compress(raw)
    return DetailLayer(step, dtype, data)


def _forward(block: np.ndarray) -> np.ndarray:
    """(3, 21, 90, 90) residual → DCT coefficients of the decorrelated colours."""
    y = np.einsum("ac,cshd->ashd", COLOUR_MATRIX, block)
    y = np.einsum("fs,ashd->afhd", _dct_matrix(_SHAPE[1]), y)
    y = np.einsum("gh,afhd->afgd", _dct_matrix(_SHAPE[2]), y)
    return np.einsum("ed,afgd->afge", _dct_matrix(_SHAPE[3]), y)


def check_detail_frame(data: bytes, dtype: str) -> None:
    """Check a detail layer's bytes as a reader must when the record is read (``spec/bvae-format.md`` §4.4, §7):
    exactly one zstandard frame, nothing after it, that declares and holds ``63·90·90`` integers of ``dtype``.

    The frame is decompressed whole (bounded by the declared size), so that a file a tool describes without
    error also decodes.

    Raises
    ------
    ValueError
        What is wrong with the frame (the reader wraps it in a format error naming the file and the record).
    """
    import zstandard

    expected = N_DETAIL_VALUES * _DTYPES[dtype].itemsize
    try:
        declared = zstandard.get_frame_parameters(data).content_size
    except zstandard.ZstdError as error:
        raise ValueError(f"detail layer is not a zstandard frame ({error})") from None
    if declared != expected:
        shown = "no content size" if declared == zstandard.CONTENTSIZE_UNKNOWN else f"{declared} bytes of content"
        raise ValueError(f"detail layer declares {shown}, expected {expected} ({dtype})")
    stream = zstandard.ZstdDecompressor(max_window_size=_MAX_WINDOW).decompressobj()
    try:
        raw = stream.decompress(data)  # bounded: the frame declares its size, checked above
    except zstandard.ZstdError as error:
        raise ValueError(f"detail layer's frame cannot be decompressed ({error})") from None
    if len(raw) != expected or not stream.eof:
        raise ValueError(f"detail layer's frame is truncated: it holds {len(raw)} of the {expected} bytes it declares")
    if stream.unused_data:
        raise ValueError(f"{len(stream.unused_data)} bytes after the detail layer's zstandard frame "
                         "(the layer is exactly one frame)")


def _stored_integers(layer: DetailLayer, path: str = "<detail>") -> np.ndarray:
    """The quantised coefficients of a layer as stored (int16 or int32), flat in the (3, 21, 90, 90) C order.

    Raises
    ------
    ValueError
        The frame does not decompress to exactly ``63·90·90`` integers.
    """
    import zstandard

    expected = N_DETAIL_VALUES * _DTYPES[layer.dtype].itemsize
    try:
        params = zstandard.get_frame_parameters(layer.data)
        if params.content_size != expected:
            raise ValueError(f"{path}: detail layer declares {params.content_size} bytes, expected {expected}")
        raw = zstandard.ZstdDecompressor().decompress(layer.data, max_output_size=expected)
    except zstandard.ZstdError as error:
        raise ValueError(f"{path}: detail layer cannot be decompressed ({error})") from None
    if len(raw) != expected:
        raise ValueError(f"{path}: detail layer holds {len(raw)} bytes, expected {expected}")
    return np.frombuffer(raw, dtype=_DTYPES[layer.dtype])


def decode_detail(layer: DetailLayer, slots: Sequence[int] | None = None) -> npt.NDArray[np.float32]:
    """The residual a layer codes, in mapped units.

    Parameters
    ----------
    layer : DetailLayer
    slots : sequence of int, optional
        Kept-slice positions (0–20) to reconstruct; all 21 by default.

    Returns
    -------
    ndarray of float32, shape (3, len(slots), 90, 90)
        Colour-major: ``out[c, i]`` is colour c at kept slot ``slots[i]``;
        reshape to ``(63, 90, 90)`` for the network layout when all slots are asked for.
    """
    chosen = list(range(N_KEPT_SLICES)) if slots is None else [int(s) for s in slots]
    if not chosen or min(chosen) < 0 or max(chosen) >= N_KEPT_SLICES:
        raise ValueError(f"slots must be kept-slice positions in [0, {N_KEPT_SLICES}), got {slots}")
    q = _stored_integers(layer).reshape(N_CHANNELS * N_KEPT_SLICES, *_SHAPE[2:])  # (63, 90, 90) coefficients
    # At the rates a detail layer is used most coefficients are 0, and the nonzero ones are low frequencies:
    # each (colour, slice frequency) plane is inverted over the block [0, h) × [0, d) that holds its nonzero
    # coefficients, and all-zero planes are skipped. Dense layers (fine steps) take the batched products.
    rows_used = np.bitwise_or.reduce(q, axis=2) != 0  # (63, 90): θh frequency used in the plane
    cols_used = np.bitwise_or.reduce(q, axis=1) != 0  # (63, 90): θd frequency used
    planes = np.flatnonzero(rows_used.any(axis=1))
    out = np.zeros((N_CHANNELS, len(chosen), *_SHAPE[2:]), dtype=np.float32)
    if len(planes) == 0:
        return out
    n_h, n_d = _SHAPE[2], _SHAPE[3]
    rows = n_h - np.argmax(rows_used[planes, ::-1], axis=1)
    cols = n_d - np.argmax(cols_used[planes, ::-1], axis=1)
    # binary64 products (issue 49): with |q| up to 2^15 and large steps, binary32 sums drift by 1e-3 mapped, beyond
    # the conformance tolerance (§4.4, §9); the result is rounded to float32 once.
    inverse_h, inverse_d = _dct_matrix_f64(n_h).T, _dct_matrix_f64(n_d)
    sparse_work = int(np.sum(rows * n_h * (np.minimum(rows, cols) + n_d)))
    if sparse_work > _DENSE_SHARE * len(planes) * 2 * n_h * n_h * n_d:
        x = np.matmul(inverse_h, np.matmul(q[planes].astype(np.float64), inverse_d))
    else:
        x = np.empty((len(planes), n_h, n_d), dtype=np.float64)
        for i, (plane, h, d) in enumerate(zip(planes, rows, cols, strict=True)):
            block = q[plane, :h, :d].astype(np.float64)
            if h <= d:  # the cheaper order of the two products
                np.matmul(inverse_h[:, :h], block @ inverse_d[:d], out=x[i])
            else:
                np.matmul(inverse_h[:, :h] @ block, inverse_d[:d], out=x[i])
    # The slice inverse of each colour over its used slice frequencies, then the colour inverse and the step.
    n_slots = len(chosen)
    slice_inverse = _dct_matrix_f64(_SHAPE[1])[:, chosen].T  # (slots, slice frequencies)
    by_colour = np.zeros((N_CHANNELS, n_slots * n_h * n_d), dtype=np.float64)
    flat = x.reshape(len(planes), -1)
    colour_of_plane, frequency_of_plane = np.divmod(planes, _SHAPE[1])
    for colour in range(N_CHANNELS):
        mine = np.flatnonzero(colour_of_plane == colour)
        if len(mine):
            target = by_colour[colour].reshape(n_slots, -1)
            np.matmul(slice_inverse[:, frequency_of_plane[mine]], flat[mine], out=target)
    colour_inverse = COLOUR_MATRIX.T.astype(np.float64) * layer.step
    out.reshape(N_CHANNELS, -1)[...] = colour_inverse @ by_colour
    return out


@functools.cache
def _dct_matrix_f64(n: int) -> np.ndarray:
    """:func:`_dct_matrix` in float64 (the detail layer's inverse is computed in binary64)."""
    matrix = _dct_matrix(n).astype(np.float64)
    matrix.setflags(write=False)
    return matrix
