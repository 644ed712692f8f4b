"""Reading and writing MERL ``.binary`` BRDF tables.

File layout (``spec/conventions.md`` §1): three little-endian int32
``(90, 90, 180)``, then three blocks (R, G, B) of ``90·90·180`` little-endian
float64, entry ``φd + 180·(θd + 90·θh)`` within a block. The file holds
*stored* values; reflectance in 1/sr is stored value × colour scale.
"""

from __future__ import annotations

import functools
import hashlib
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import MERL_SHAPE, TABLE_SHAPE, UNMEASURED_VALUE
from brdfcodec.errors import MerlFormatError, NonFiniteValueError
from brdfcodec.io.atomic import atomic_output
from brdfcodec.io.file_kinds import sniff_file_kind
from brdfcodec.io.hashing import sha256_of_file
from brdfcodec.representation.mask import validity_mask
from brdfcodec.representation.units import reflectance_from_stored

__all__ = [
    "MERL_FILE_SIZE",
    "MERL_HEADER",
    "MerlBRDF",
    "read_merl",
    "source_digest",
    "write_merl",
]

#: struct format of the header: three little-endian int32.
MERL_HEADER = struct.Struct("<3i")
_N_ENTRIES = int(np.prod(TABLE_SHAPE))
#: Exact size in bytes of a MERL file (34,992,012).
MERL_FILE_SIZE = MERL_HEADER.size + 8 * _N_ENTRIES
_FILE_DTYPE = np.dtype("<f8")

NonFinitePolicy = Literal["error", "mask"]


@dataclass(frozen=True, eq=False)
class MerlBRDF:
    """A measured BRDF table in MERL layout.

    Parameters
    ----------
    values : ndarray of float64, shape (3, 90, 90, 180)
        Stored values indexed ``[channel, θh, θd, φd]``. Negative entries are
        unmeasured; every entry is finite.
    name : str, optional
        Material name (by default the file's stem).
    path : pathlib.Path, optional
        File it was read from.
    source_kind : str, optional
        Where the table comes from when it was not read from a MERL file
        (``"rgl-measured"``, ``"nbrdf-proxy"``, ``"analytic"``); None for a
        MERL file.
    source_sha256 : str, optional
        SHA-256 of the source file it was tabulated from, when that is not a
        MERL file (e.g. an RGL ``.bsdf``); None otherwise.
    """

    values: npt.NDArray[np.float64]
    name: str | None = None
    path: Path | None = None
    _file_sha256: str | None = field(default=None, repr=False)
    source_kind: str | None = None
    source_sha256: str | None = None

    def __post_init__(self) -> None:
        if self.values.shape != TABLE_SHAPE:
            raise ValueError(f"values must have shape {TABLE_SHAPE}, got {self.values.shape}")
        if self.values.dtype != np.float64:
            raise ValueError(f"values must be float64, got {self.values.dtype}")

    @functools.cached_property
    def mask(self) -> npt.NDArray[np.bool_]:
        """Valid entries (above the horizon, measured), shape (3, 90, 90, 180)."""
        return validity_mask(self.values)

    @property
    def valid_fraction(self) -> float:
        """Fraction of entries that are valid, in [0, 1]."""
        return float(self.mask.mean())

    def reflectance(self) -> npt.NDArray[np.float64]:
        """Linear RGB reflectance in 1/sr, with invalid entries set to 0.

        Returns
        -------
        ndarray of float64, shape (3, 90, 90, 180)
        """
        return np.where(self.mask, reflectance_from_stored(self.values), 0.0)

    #: Former name of :meth:`reflectance`.
    physical = reflectance

    @functools.cached_property
    def sha256(self) -> str:
        """SHA-256 (hex) of the file bytes this table writes to (and was read from)."""
        if self._file_sha256 is not None:
            return self._file_sha256
        digest = hashlib.sha256(MERL_HEADER.pack(*MERL_SHAPE))
        digest.update(np.ascontiguousarray(self.values, dtype=_FILE_DTYPE).data)
        return digest.hexdigest()

    def eval(
        self,
        wi: npt.ArrayLike,
        wo: npt.ArrayLike,
        *,
        mode: Literal["nearest", "trilinear"] = "nearest",
    ) -> npt.NDArray[np.float64]:
        """Reflectance (1/sr, linear RGB) for direction pairs.

        See :func:`brdfcodec.representation.lookup.lookup`; this is a shortcut with the
        table's :meth:`physical` values and :attr:`mask`.
        """
        from brdfcodec.representation.lookup import lookup

        return lookup(self.reflectance(), wi, wo, mode=mode, mask=self.mask)


def _check_header(path: Path, header: bytes, size: int) -> None:
    if size < MERL_HEADER.size:
        kind = sniff_file_kind(header)
        what = f" ({kind})" if kind is not None else ""
        raise MerlFormatError(path, f"file is {size} bytes{what}, too short for the 12-byte MERL header")
    dims = MERL_HEADER.unpack(header)
    if dims != MERL_SHAPE:
        kind = sniff_file_kind(header)
        if kind is not None:  # a known other format: say what it is, not its first bytes read as int32
            raise MerlFormatError(
                path,
                f"this is {kind}, not a MERL BRDF .binary file (a 12-byte header of three int32 {MERL_SHAPE}, "
                f"then {MERL_FILE_SIZE - MERL_HEADER.size:,} bytes of float64: {MERL_FILE_SIZE:,} bytes in all)",
            )
        raise MerlFormatError(
            path,
            f"header gives dimensions {dims}, expected {MERL_SHAPE}: not a MERL BRDF .binary file "
            "(or one of another resolution, which brdfcodec does not read)",
        )
    if size != MERL_FILE_SIZE:
        kind = "truncated" if size < MERL_FILE_SIZE else "has trailing bytes"
        raise MerlFormatError(path, f"file {kind}: {size} bytes, a MERL file has exactly {MERL_FILE_SIZE}")


def source_digest(brdf: MerlBRDF) -> str:
    """The SHA-256 a record names its source by (``meta.source_sha256``): the measurement's own where the table
    was converted from one (``source_sha256``, RGL), else the MERL file's (:attr:`MerlBRDF.sha256`)."""
    return brdf.source_sha256 or brdf.sha256


def read_merl(
    path: str | os.PathLike[str],
    *,
    nonfinite: NonFinitePolicy = "error",
    name: str | None = None,
) -> MerlBRDF:
    """Read a MERL ``.binary`` file.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    nonfinite : {"error", "mask"}, default "error"
        What to do with NaN or infinite values: raise
        :class:`~brdfcodec.errors.NonFiniteValueError`, or store them as
        unmeasured (:data:`~brdfcodec.conventions.UNMEASURED_VALUE`) so they
        are masked.
    name : str, optional
        Material name; the file's stem by default.

    Returns
    -------
    MerlBRDF

    Raises
    ------
    MerlFormatError
        Wrong header, truncated file or trailing bytes.
    NonFiniteValueError
        NaN or infinite values with ``nonfinite="error"``.
    FileNotFoundError, IsADirectoryError, PermissionError
        The path cannot be read as a file.
    """
    if nonfinite not in ("error", "mask"):
        raise ValueError(f"nonfinite must be 'error' or 'mask', got {nonfinite!r}")
    file_path = Path(path)
    if file_path.is_dir():
        raise IsADirectoryError(f"{file_path}: is a directory, expected a MERL .binary file")
    with open(file_path, "rb") as stream:
        size = os.fstat(stream.fileno()).st_size
        header = stream.read(MERL_HEADER.size)
        _check_header(file_path, header, size)
        flat = np.fromfile(stream, dtype=_FILE_DTYPE, count=_N_ENTRIES)
    if flat.size != _N_ENTRIES:  # the file shrank under us
        raise MerlFormatError(file_path, "file truncated while reading")
    values = flat.astype(np.float64, copy=False).reshape(TABLE_SHAPE)
    file_sha256 = None
    finite = np.isfinite(values)
    if not finite.all():
        n_bad = int(values.size - np.count_nonzero(finite))
        if nonfinite == "error":
            first = np.unravel_index(int(np.argmin(finite)), TABLE_SHAPE)
            raise NonFiniteValueError(
                file_path,
                f"{n_bad} NaN or infinite values (first at [channel, θh, θd, φd] = "
                f"{tuple(int(i) for i in first)}); read with nonfinite='mask' to treat them as unmeasured",
            )
        file_sha256 = sha256_of_file(file_path)
        values = np.where(finite, values, UNMEASURED_VALUE)
    return MerlBRDF(values, name=name or file_path.stem, path=file_path, _file_sha256=file_sha256)


def write_merl(
    path: str | os.PathLike[str],
    values: npt.ArrayLike | MerlBRDF,
    *,
    overwrite: bool = False,
) -> Path:
    """Write a table as a MERL ``.binary`` file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.
    values : array_like of shape (3, 90, 90, 180), or MerlBRDF
        Stored values (not physical reflectance). Use
        :data:`~brdfcodec.conventions.UNMEASURED_VALUE` for unmeasured entries.
    overwrite : bool, default False
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    ValueError
        Wrong shape, or NaN / infinite values (MERL files hold none).
    FileExistsError
        The file exists and ``overwrite`` is false.
    """
    table = values.values if isinstance(values, MerlBRDF) else np.asarray(values)
    if table.shape != TABLE_SHAPE:
        raise ValueError(f"table must have shape {TABLE_SHAPE}, got {table.shape}")
    if not np.isfinite(table).all():
        raise ValueError("table holds NaN or infinite values; MERL files hold none (use -1 for unmeasured)")
    data = np.ascontiguousarray(table, dtype=_FILE_DTYPE)
    with atomic_output(path, overwrite=overwrite) as tmp, open(tmp, "wb") as stream:
        stream.write(MERL_HEADER.pack(*MERL_SHAPE))
        data.tofile(stream)
    return Path(path)
