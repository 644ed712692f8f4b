"""Small Mitsuba tensor files (the RGL ``.bsdf`` container) written byte by byte, for tests and fuzzing.

Layout (Mitsuba's ``TensorFile``): the 12-byte magic, version (2 × u8), field count (u32), then per field its
name length (u16), name, dimension count (u16), type code (u8), data offset (u64) and shape (u64 each); then
the data. Nothing here depends on Mitsuba or on the shared data.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence

import numpy as np

MAGIC = b"tensor_file\x00"
#: Mitsuba's type codes of the NumPy types used here.
CODES = {"u1": 1, "<f4": 10, "<f8": 11, "<u4": 5}


def tensor_file(fields: Mapping[str, np.ndarray], *, shapes: Mapping[str, Sequence[int]] | None = None,
                codes: Mapping[str, int] | None = None, version: tuple[int, int] = (1, 0)) -> bytes:
    """A tensor file holding ``fields`` (name → array), with declared ``shapes`` and type ``codes`` overriding
    the arrays' own where given (the data written stays the array's)."""
    shapes, codes = dict(shapes or {}), dict(codes or {})
    entries = []
    for name, array in fields.items():
        array = np.ascontiguousarray(array)
        entries.append((name.encode("ascii"), codes.get(name, CODES[array.dtype.str if array.dtype.itemsize > 1
                                                                     else "u1"]),
                        tuple(shapes.get(name, array.shape)), array.tobytes()))
    header_size = len(MAGIC) + 2 + 4 + sum(2 + len(n) + 2 + 1 + 8 + 8 * len(s) for n, _, s, _ in entries)
    header = bytearray(MAGIC + struct.pack("<BBI", *version, len(entries)))
    body = bytearray()
    for name, code, shape, data in entries:
        offset = header_size + len(body)
        header += struct.pack("<H", len(name)) + name + struct.pack("<HBQ", len(shape), code, offset)
        header += b"".join(struct.pack("<Q", n) for n in shape)
        body += data + b"\x00" * (-len(data) % 8)
    return bytes(header + body)


def small_rgl_fields(n_theta: int = 3, grid: int = 4, seed: int = 0) -> dict[str, np.ndarray]:
    """The fields of a small, valid, isotropic RGB measurement (what the ``measured`` plugin reads, plus the
    ``version`` and ``valid`` fields of the database's files)."""
    rng = np.random.default_rng(seed)
    positive = lambda *shape: rng.uniform(0.05, 1.0, shape).astype("<f4")  # noqa: E731
    return {
        "version": np.array([1, 0], dtype="<u4"),
        "description": np.frombuffer(b"synthetic test material", dtype="u1"),
        "phi_i": np.zeros(1, dtype="<f4"),
        "theta_i": np.linspace(0.0, np.pi / 2, n_theta, dtype="<f4"),
        "sigma": positive(2, 8),
        "ndf": positive(2, 8),
        "vndf": positive(1, n_theta, 8, 8),
        "luminance": positive(1, n_theta, grid, grid),
        "rgb": positive(1, n_theta, 3, grid, grid),
        "jacobian": np.ones(1, dtype="u1"),
        "valid": np.full(grid * grid, 255, dtype="u1"),
    }


def field_shape_position(data: bytes, name: bytes) -> int:
    """Byte position of the first shape entry of a field in a tensor-file header."""
    start = data.index(struct.pack("<H", len(name)) + name) + 2 + len(name)
    return start + 2 + 1 + 8  # ndim (u16), dtype (u8), offset (u64)
