"""Real RGL measurements: the EPFL RGL database's ``.bsdf`` files, tabulated on the MERL grid.

The RGL material database (Dupuy and Jakob 2018) stores each measurement as
a Mitsuba *tensor file* (``.bsdf``), read by Mitsuba 3's ``measured`` plugin,
the field's reference reader. brdfcodec does not re-implement that reader:
:func:`read_rgl_bsdf` loads the file with Mitsuba's own plugin and evaluates
it, vectorised (Dr.Jit's LLVM backend where a usable libLLVM is found, else
``scalar_rgb``), at every MERL bin's representative direction pair.

Conventions of the tabulation (``spec/conventions.md`` §9, as for the NBRDF
proxy): angles are the bins' representative angles
(:func:`brdfcodec.representation.coords.grid_angles`); Mitsuba's ``eval`` includes the
cosine of the outgoing direction, which is divided out to give the BRDF in
1/sr; entries with either direction below the horizon are unmeasured
(:data:`~brdfcodec.conventions.UNMEASURED_VALUE`); stored values are the
reflectance divided by MERL's colour scale, so the table is a MERL table in
every respect and round-trips through :func:`brdfcodec.io.merl.write_merl`.

Only isotropic RGB files are accepted: an anisotropic file (more than one
incident azimuth φi) or a spectral one (a ``spectra`` field instead of
``rgb``) is refused with :class:`~brdfcodec.errors.SourceFormatError`.

:func:`read_rgl_header` inspects a file's fields without Mitsuba (and
without torch), for ``bvae info`` and for refusing unsupported files before
Mitsuba is loaded.
"""

from __future__ import annotations

import contextlib
import math
import os
import struct
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.conventions import UNMEASURED_VALUE
from brdfcodec.errors import OptionalDependencyError, SourceFormatError
from brdfcodec.io.hashing import sha256_of_file
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.representation import stored_from_reflectance
from brdfcodec.representation.coords import directions_from_half_diff, grid_angles
from brdfcodec.representation.mask import horizon_mask

__all__ = [
    "RGL_SOURCE_KIND",
    "TENSOR_FILE_MAGIC",
    "MAX_FIELD_VALUE",
    "MIN_ANGLE_STEP",
    "MIN_SIGMA",
    "MIN_VNDF_PEAK",
    "NegativeColourWarning",
    "RglHeader",
    "is_rgl_file",
    "read_rgl_bsdf",
    "read_rgl_header",
]

#: ``source_kind`` of materials tabulated from real RGL measurements.
RGL_SOURCE_KIND = "rgl-measured"

#: First 12 bytes of a Mitsuba tensor file (the RGL ``.bsdf`` container).
TENSOR_FILE_MAGIC = b"tensor_file\x00"

# Mitsuba's tensor-file dtype codes (mitsuba/core/tensor.h, Struct::Type) → NumPy.
_DTYPES = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8", 9: "<f2", 10: "<f4", 11: "<f8"}
_REQUIRED_FIELDS = ("theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "valid")
_TENSOR_FILE_VERSION = (1, 0)
_MAX_FIELDS = 256
_MAX_DIMENSIONS = 8


@dataclass(frozen=True)
class RglField:
    """One field of a tensor file: its NumPy dtype string, byte offset and shape."""

    dtype: str
    offset: int
    shape: tuple[int, ...]

    @property
    def count(self) -> int:
        """Number of values the field holds (a Python integer: a declared shape cannot overflow it)."""
        return math.prod(self.shape)

    @property
    def nbytes(self) -> int:
        """Bytes the field's data occupies (a Python integer)."""
        return np.dtype(self.dtype).itemsize * self.count


@dataclass(frozen=True)
class RglHeader:
    """What a ``.bsdf`` file holds, read from its header alone.

    Attributes
    ----------
    path : pathlib.Path
        The file.
    version : tuple of int
        Tensor-file format version (major, minor).
    fields : dict of str to RglField
        Every field by name.
    description : str
        The database's description of the material ("" when absent).
    """

    path: Path
    version: tuple[int, int]
    fields: dict[str, RglField]
    description: str

    @property
    def isotropic(self) -> bool:
        """Whether the measurement has a single incident azimuth φi (the database's isotropic layout)."""
        return self.fields["phi_i"].shape == (1,)

    @property
    def colour(self) -> str:
        """``"rgb"``, ``"spectral"`` or ``"none"``: how the file stores colour."""
        if "rgb" in self.fields:
            return "rgb"
        if "spectra" in self.fields:
            return "spectral"
        return "none"

    @property
    def theta_i_count(self) -> int:
        """Number of measured incident elevations."""
        return self.fields["theta_i"].count


def is_rgl_file(path: str | os.PathLike[str]) -> bool:
    """Whether a file starts with the tensor-file magic (cheap; reads 12 bytes)."""
    try:
        with open(path, "rb") as stream:
            return stream.read(len(TENSOR_FILE_MAGIC)) == TENSOR_FILE_MAGIC
    except OSError:
        return False


def read_rgl_header(path: str | os.PathLike[str]) -> RglHeader:
    """Read and check the header of an RGL ``.bsdf`` tensor file (no Mitsuba, no torch).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    RglHeader

    Raises
    ------
    SourceFormatError
        Not a tensor file, a truncated or inconsistent header, a field outside
        the file, or a field the ``measured`` plugin needs is missing.
    FileNotFoundError, IsADirectoryError, PermissionError
        The path cannot be read as a file.
    """
    file_path = Path(path)
    if file_path.is_dir():
        raise IsADirectoryError(f"{file_path}: is a directory, expected an RGL .bsdf file")
    with open(file_path, "rb") as stream:
        size = os.fstat(stream.fileno()).st_size
        head = stream.read(min(size, 1 << 16))
    if not head.startswith(TENSOR_FILE_MAGIC):
        raise SourceFormatError(file_path, "not an RGL .bsdf file (no Mitsuba tensor-file magic)")
    reader = _HeaderReader(file_path, head, len(TENSOR_FILE_MAGIC))
    version = (reader.unpack("<B"), reader.unpack("<B"))
    n_fields = reader.unpack("<I")
    if n_fields > _MAX_FIELDS:
        raise SourceFormatError(file_path, f"header declares {n_fields} fields, more than {_MAX_FIELDS}")
    if version != _TENSOR_FILE_VERSION:
        raise SourceFormatError(
            file_path, f"tensor-file version {version[0]}.{version[1]} is not the 1.0 that Mitsuba reads"
        )
    fields: dict[str, RglField] = {}
    for _ in range(n_fields):
        name = reader.take(reader.unpack("<H")).decode("ascii", errors="replace")
        if name in fields:
            raise SourceFormatError(file_path, f"field {name!r} appears twice in the header")
        ndim = reader.unpack("<H")
        code = reader.unpack("<B")
        offset = reader.unpack("<Q")
        if ndim > _MAX_DIMENSIONS:
            raise SourceFormatError(file_path, f"field {name!r} has {ndim} dimensions")
        shape = tuple(reader.unpack("<Q") for _ in range(ndim))
        if code not in _DTYPES:
            raise SourceFormatError(file_path, f"field {name!r} has unknown type code {code}")
        entry = RglField(_DTYPES[code], offset, shape)
        if offset + entry.nbytes > size:  # Python integers: a huge declared shape cannot wrap around
            raise SourceFormatError(
                file_path, f"field {name!r} (shape {list(shape)}) extends past the end of the file (truncated?)"
            )
        fields[name] = entry
    _check_layout(file_path, fields, reader.position)
    missing = [name for name in _REQUIRED_FIELDS if name not in fields]
    if missing:
        raise SourceFormatError(file_path, f"not an RGL BRDF measurement: missing field(s) {', '.join(missing)}")
    description = ""
    if "description" in fields:
        entry = fields["description"]
        with open(file_path, "rb") as stream:
            stream.seek(entry.offset)
            description = stream.read(entry.nbytes).decode("utf-8", errors="replace").rstrip("\x00")
    return RglHeader(file_path, version, fields, description)


def _check_layout(path: Path, fields: dict[str, RglField], header_end: int) -> None:
    """Refuse fields whose bytes lie inside the header (which ends at byte ``header_end``) or overlap another
    field's: each byte of a tensor file belongs to one field at most, so that a field cannot be read as two."""
    spans = sorted((field.offset, field.offset + field.nbytes, name) for name, field in fields.items()
                   if field.nbytes > 0)
    for start, _, name in spans:
        if start < header_end:
            raise SourceFormatError(
                path, f"field {name!r} starts at byte {start}, inside the header (which ends at byte {header_end})"
            )
    for (_, end, first), (start, _, second) in zip(spans, spans[1:], strict=False):
        if start < end:
            raise SourceFormatError(path, f"fields {first!r} and {second!r} overlap (bytes {start} to {end - 1})")


class _HeaderReader:
    """Sequential little-endian reads from a header buffer, with a clear error when it runs out."""

    def __init__(self, path: Path, data: bytes, position: int) -> None:
        self.path, self.data, self.position = path, data, position

    def take(self, count: int) -> bytes:
        end = self.position + count
        if end > len(self.data):
            raise SourceFormatError(self.path, "tensor-file header is truncated")
        chunk = self.data[self.position : end]
        self.position = end
        return chunk

    def unpack(self, fmt: str) -> int:
        (value,) = struct.unpack(fmt, self.take(struct.calcsize(fmt)))
        return int(value)


def check_supported(header: RglHeader) -> None:
    """Refuse what brdfcodec cannot tabulate on the MERL grid, and every file Mitsuba's ``measured`` plugin would
    refuse or misread: anisotropic or non-RGB files, and fields of the wrong type, shape or value.

    Every field the plugin reads is checked here, before Mitsuba sees the file (:func:`check_measured_fields`),
    so that ``bvae info`` says "reads yes" only for files that ``bvae compress`` reads.

    Raises
    ------
    SourceFormatError
        With a message naming the file and saying what the file is and what is accepted (or which field is
        wrong).
    """
    _check_field(header, "phi_i", ndim=1)
    if not header.isotropic:
        raise SourceFormatError(
            header.path,
            f"anisotropic RGL measurement ({header.fields['phi_i'].shape[0]} incident azimuths): "
            "the MERL grid is isotropic; brdfcodec reads isotropic RGL files only",
        )
    if header.colour == "spectral":
        raise SourceFormatError(
            header.path, "spectral RGL file: use the RGB version of the measurement (the database's *_rgb.bsdf)"
        )
    if header.colour != "rgb":
        raise SourceFormatError(header.path, "RGL file holds no RGB data (no 'rgb' field)")
    check_measured_fields(header)


#: The fields Mitsuba's ``measured`` plugin reads from an RGB file, with their number of dimensions and type.
_MEASURED_FIELDS = {
    "description": (1, "u1"),
    "jacobian": (1, "u1"),
    "theta_i": (1, "<f4"),
    "phi_i": (1, "<f4"),
    "ndf": (2, "<f4"),
    "sigma": (2, "<f4"),
    "vndf": (4, "<f4"),
    "luminance": (4, "<f4"),
    "rgb": (5, "<f4"),
}
#: Fields whose values the plugin turns into sampling distributions: finite and ≥ 0.
_DENSITY_FIELDS = ("ndf", "sigma", "vndf", "luminance")


def _check_field(header: RglHeader, name: str, *, ndim: int, dtype: str = "<f4") -> RglField:
    """A field the ``measured`` plugin reads, refused unless it exists with ``ndim`` dimensions of ``dtype``
    and no empty dimension."""
    field = header.fields.get(name)
    if field is None:
        raise SourceFormatError(header.path, f"not an RGL BRDF measurement: missing field {name!r}")
    if field.dtype != dtype or len(field.shape) != ndim or 0 in field.shape:
        raise SourceFormatError(
            header.path,
            f"field {name!r} is {np.dtype(field.dtype).name} of shape {list(field.shape)}; Mitsuba's measured "
            f"plugin needs {np.dtype(dtype).name} with {ndim} non-empty dimension(s)",
        )
    return field


class NegativeColourWarning(UserWarning):
    """An RGL file's ``rgb`` field holds negative values, which the MERL table cannot store (clipped to 0)."""


#: Largest magnitude accepted in the density and colour fields. The plugin multiplies them in float32
#: (f = rgb · D / (4 σ)): with every factor within [1e-10, 1e10] no product overflows (≤ 2.5e29 < 3.4e38).
#: The database's files hold values below 1e3.
MAX_FIELD_VALUE = 1e10
#: Smallest projected area σ accepted: the plugin divides by it (the database's files: above 0.01).
MIN_SIGMA = 1e-10
#: Smallest largest value of a VNDF slice: the plugin scales each slice to a probability density, in float32;
#: a slice of zeros or of denormals has none (the scale is infinite).
MIN_VNDF_PEAK = 1e-20
#: Smallest step between two incident angles, radians: the plugin interpolates between them in float32
#: (a step that underflows gives an infinite weight). The database's steps are about 0.2 rad.
MIN_ANGLE_STEP = 1e-6
#: Largest incident elevation accepted, radians (π/2 plus float32's rounding of it).
_MAX_THETA_I = math.pi / 2 + 1e-5
#: Values read at a time when checking a large field.
_CHUNK_VALUES = 1 << 20


def check_measured_fields(header: RglHeader) -> None:
    """Refuse a file whose fields Mitsuba's ``measured`` plugin would refuse, misread or crash on, or whose
    evaluation would not be finite.

    Checks the type, dimensions and agreeing sizes of every field the plugin reads (``description``,
    ``jacobian``, ``theta_i``, ``phi_i``, ``ndf``, ``sigma``, ``vndf``, ``luminance``, ``rgb``), the
    byte range of each (done by :func:`read_rgl_header`, in Python integers), and their values:

    * the angle grids finite and strictly increasing in steps of at least :data:`MIN_ANGLE_STEP` radians,
      ``theta_i`` within [0, π/2];
    * ``sigma`` (the divisor of every evaluation) within [:data:`MIN_SIGMA`, :data:`MAX_FIELD_VALUE`];
    * ``ndf``, ``vndf`` and ``luminance`` finite, ≥ 0 and at most :data:`MAX_FIELD_VALUE`; each
      (φi, θi) slice of ``vndf`` with a largest value of at least :data:`MIN_VNDF_PEAK` (the plugin scales
      each slice to a density);
    * ``rgb`` finite and within ±:data:`MAX_FIELD_VALUE`. Negative colours (from a conversion of spectra
      out of the sRGB gamut) are accepted with a :class:`NegativeColourWarning` that counts them (the MERL
      table clips them to 0), unless no colour value is positive: such a file is refused.

    Memory stays bounded: fields are read a slice (or :data:`_CHUNK_VALUES` values) at a time.

    Raises
    ------
    SourceFormatError
        Naming the file and the field.
    """
    for name, (ndim, dtype) in _MEASURED_FIELDS.items():
        _check_field(header, name, ndim=ndim, dtype=dtype)
    fields, path = header.fields, header.path
    n_phi, n_theta = fields["phi_i"].shape[0], fields["theta_i"].shape[0]
    if fields["jacobian"].shape != (1,):
        raise SourceFormatError(path, f"field 'jacobian' has shape {list(fields['jacobian'].shape)}, expected [1]")
    for name in ("ndf", "sigma"):
        if min(fields[name].shape) < 2:
            raise SourceFormatError(path, f"field {name!r} has shape {list(fields[name].shape)}: "
                                    "each dimension needs at least 2 entries")
    grid = fields["luminance"].shape[2:]
    for name, expected in (
        ("vndf", (n_phi, n_theta)),
        ("luminance", (n_phi, n_theta, grid[0], grid[0])),
        ("rgb", (n_phi, n_theta, 3, *grid)),
    ):
        shape = fields[name].shape
        if shape[: len(expected)] != expected or min(shape[-2:]) < 2:
            want = ", ".join(map(str, expected))
            raise SourceFormatError(
                path, f"field {name!r} has shape {list(shape)}; the measured plugin needs [{want}, …] "
                "(incident azimuths, elevations, then a square grid of at least 2 × 2 for luminance and rgb)"
            )
    with open(path, "rb") as stream:
        for name in ("theta_i", "phi_i"):
            _check_angles(path, name, _field_values(stream, path, name, fields[name]))
        for name in ("sigma", "ndf", "luminance"):
            for values in _field_chunks(stream, path, name, fields[name]):
                _check_range(path, name, values, low=MIN_SIGMA if name == "sigma" else 0.0)
        vndf = fields["vndf"]
        for index, values in enumerate(_field_chunks(stream, path, "vndf", vndf, per=math.prod(vndf.shape[2:]))):
            _check_range(path, "vndf", values, low=0.0)
            if not values.max() >= MIN_VNDF_PEAK:
                phi, theta = divmod(index, n_theta)
                raise SourceFormatError(
                    path, f"field 'vndf' has no positive density for incident direction (φi {phi}, θi {theta}): "
                    f"its largest value is {float(values.max()):.3g}, below {MIN_VNDF_PEAK:g} (the measured plugin "
                    "scales each slice to a probability density)"
                )
        negative, total, lowest, positive = 0, fields["rgb"].count, 0.0, False
        for values in _field_chunks(stream, path, "rgb", fields["rgb"]):
            _check_range(path, "rgb", values, low=-MAX_FIELD_VALUE)
            below = values < 0
            positive = positive or bool((values > 0).any())
            if below.any():
                negative += int(below.sum())
                lowest = min(lowest, float(values.min()))
    if negative and not positive:
        raise SourceFormatError(
            path, f"field 'rgb' holds no positive value and {negative:,} negative ones (lowest {lowest:.3g}): "
            "not a reflectance measurement"
        )
    if negative:
        warnings.warn(
            f"{path}: field 'rgb' holds {negative:,} negative values of {total:,} ({100 * negative / total:.3g} %, "
            f"lowest {lowest:.3g}); they are read as 0 (a MERL table stores no negative reflectance)",
            NegativeColourWarning,
            stacklevel=3,
        )


def _check_angles(path: Path, name: str, values: np.ndarray) -> None:
    """Incident angles: finite, strictly increasing in steps of at least :data:`MIN_ANGLE_STEP`; θi in [0, π/2]."""
    if not np.isfinite(values).all():
        raise SourceFormatError(path, f"field {name!r} holds non-finite values")
    steps = np.diff(values.astype(np.float64))
    if np.any(steps <= 0):
        raise SourceFormatError(path, f"field {name!r} is not strictly increasing")
    if np.any(steps < MIN_ANGLE_STEP):
        raise SourceFormatError(
            path, f"field {name!r} has a step of {float(steps.min()):.3g} rad between two angles, below "
            f"{MIN_ANGLE_STEP:g} rad (the measured plugin's float32 interpolation would divide by it)"
        )
    if name == "theta_i" and (values[0] < 0 or values[-1] > _MAX_THETA_I):
        raise SourceFormatError(
            path, f"field 'theta_i' spans [{float(values[0]):.6g}, {float(values[-1]):.6g}] rad, outside the "
            "incident elevations [0, π/2]"
        )
    if name == "phi_i" and np.abs(values).max() > 2 * math.pi + 1e-5:
        raise SourceFormatError(path, "field 'phi_i' holds azimuths outside [−2π, 2π] rad")


def _check_range(path: Path, name: str, values: np.ndarray, *, low: float) -> None:
    """Values finite and within [low, :data:`MAX_FIELD_VALUE`]; a message that says which bound fails."""
    if not np.isfinite(values).all():
        raise SourceFormatError(path, f"field {name!r} holds non-finite values")
    smallest, largest = float(values.min()), float(values.max())
    if max(largest, -smallest) > MAX_FIELD_VALUE:
        raise SourceFormatError(
            path, f"field {name!r} holds {largest if largest > -smallest else smallest:.3g}, beyond "
            f"±{MAX_FIELD_VALUE:g} (the measured plugin's float32 products of the fields would overflow; measured "
            "files hold values below 1e3)"
        )
    if smallest < low:
        if low == 0.0:
            raise SourceFormatError(path, f"field {name!r} holds negative values (lowest {smallest:.3g})")
        raise SourceFormatError(
            path, f"field {name!r} holds {smallest:.3g}, below {low:g}"
            + (" (the measured plugin divides by the projected area σ)" if name == "sigma" else "")
        )


def _field_values(stream: Any, path: Path, name: str, field: RglField) -> np.ndarray:
    """A field's values, read from its byte range (already checked to lie in the file)."""
    stream.seek(field.offset)
    data = stream.read(field.nbytes)
    if len(data) != field.nbytes:
        raise SourceFormatError(path, f"field {name!r} extends past the end of the file (truncated?)")
    return np.frombuffer(data, dtype=field.dtype)


def _field_chunks(stream: Any, path: Path, name: str, field: RglField, *, per: int | None = None
                  ) -> Iterator[np.ndarray]:
    """A field's values, ``per`` at a time (default: up to :data:`_CHUNK_VALUES`), in file order."""
    step = per or max(1, min(field.count, _CHUNK_VALUES))
    itemsize = np.dtype(field.dtype).itemsize
    stream.seek(field.offset)
    for first in range(0, field.count, step):
        wanted = min(step, field.count - first) * itemsize
        data = stream.read(wanted)
        if len(data) != wanted:
            raise SourceFormatError(path, f"field {name!r} extends past the end of the file (truncated?)")
        yield np.frombuffer(data, dtype=field.dtype)


def read_rgl_bsdf(path: str | os.PathLike[str], *, name: str | None = None) -> MerlBRDF:
    """Tabulate an isotropic RGB RGL ``.bsdf`` measurement on the MERL grid.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.bsdf`` file.
    name : str, optional
        Material name; the file's stem without a trailing ``_rgb`` by default.

    Returns
    -------
    MerlBRDF
        Stored MERL units (reflectance / MERL colour scale), shape
        (3, 90, 90, 180); entries with a direction below the horizon are
        :data:`~brdfcodec.conventions.UNMEASURED_VALUE`. ``source_kind`` is
        :data:`RGL_SOURCE_KIND` and ``source_sha256`` the ``.bsdf`` file's.

    Raises
    ------
    SourceFormatError
        Not an RGL file, anisotropic, spectral, or Mitsuba refuses it.
    OptionalDependencyError
        Mitsuba 3 is not installed (``pip install "brdfcodec[rgl]"``).
    """
    header = read_rgl_header(path)
    check_supported(header)
    stored = stored_from_reflectance(_evaluate_on_grid(header.path))
    stored = np.where(horizon_mask()[None], np.maximum(stored, 0.0), UNMEASURED_VALUE)
    if not np.isfinite(stored).all():
        raise SourceFormatError(header.path, "Mitsuba's measured plugin returned non-finite values on the MERL grid")
    label = name or header.path.stem.removesuffix("_rgb")  # as brdfcodec.io.inputs.default_material_name
    return MerlBRDF(
        np.ascontiguousarray(stored, dtype=np.float64),
        name=label,
        path=header.path,
        source_kind=RGL_SOURCE_KIND,
        source_sha256=sha256_of_file(header.path),
    )


def _evaluate_on_grid(path: Path) -> np.ndarray:
    """Reflectance (1/sr) of the measurement at every MERL bin, shape (3, 90, 90, 180), float64.

    Below-horizon entries are left as whatever Mitsuba returns there (0); the
    caller masks them.
    """
    theta_h, theta_d, phi_d = grid_angles()
    wi, wo = directions_from_half_diff(theta_h, theta_d, phi_d)
    wi = wi.reshape(-1, 3)
    wo = wo.reshape(-1, 3)
    with _mitsuba_variant() as mi:
        try:
            bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
        except Exception as error:  # Mitsuba raises RuntimeError with its own (many-line) message
            raise SourceFormatError(path, f"Mitsuba's measured plugin refused the file: {_first_line(error)}") from None
        value = _eval_bsdf(mi, bsdf, wi, wo)
    cos_out = wo[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        brdf = np.where(cos_out[:, None] > 0.0, value / cos_out[:, None], 0.0)
    return np.ascontiguousarray(brdf.T.reshape(3, *theta_h.shape), dtype=np.float64)


def _first_line(error: BaseException) -> str:
    """The gist of a Mitsuba error in one line: its first line, without the dump of the file's fields that
    Mitsuba appends (``Invalid file structure: TensorFile[...]``), at most 200 characters."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    text = lines[0] if lines else type(error).__name__
    text = text.split("TensorFile[")[0].rstrip(" :[") or text
    return text if len(text) <= 200 else text[:199] + "…"


def _eval_bsdf(mi: object, bsdf: object, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Mitsuba ``eval`` (BRDF × cos θo) of direction pairs in the local frame, shape (N, 3)."""
    import drjit as dr

    m = mi  # the Mitsuba module of the active variant
    if dr.is_jit_v(m.Float):  # vectorised: the whole grid as one wavefront
        si = dr.zeros(m.SurfaceInteraction3f, wi.shape[0])
        si.wi = m.Vector3f(*(wi[:, k].astype(np.float32) for k in range(3)))
        si.sh_frame = m.Frame3f(m.Normal3f(0.0, 0.0, 1.0))
        value = bsdf.eval(m.BSDFContext(), si, m.Vector3f(*(wo[:, k].astype(np.float32) for k in range(3))))
        return np.asarray(value, dtype=np.float64).T.copy()
    out = np.empty((wi.shape[0], 3))  # scalar fallback: one call per direction pair
    si = m.SurfaceInteraction3f()
    si.sh_frame = m.Frame3f(m.Normal3f(0.0, 0.0, 1.0))
    context = m.BSDFContext()
    for i in range(wi.shape[0]):
        si.wi = m.Vector3f(*wi[i])
        out[i] = np.asarray(bsdf.eval(context, si, m.Vector3f(*wo[i])))
    return out


@contextlib.contextmanager
def _mitsuba_variant() -> Iterator[Any]:
    """Mitsuba with ``llvm_ad_rgb`` active (``scalar_rgb``, with a warning, when no usable libLLVM is found).

    The previously active variant is restored afterwards.
    """
    try:
        import mitsuba as mi
    except ImportError:
        raise OptionalDependencyError(
            "reading RGL .bsdf files needs Mitsuba 3: pip install \"brdfcodec[rgl]\""
        ) from None
    from brdfcodec.runtime.mitsuba import set_variant

    previous = mi.variant()
    variant = set_variant(("llvm_ad_rgb",), fallback="scalar_rgb", warn=False)
    if variant == "scalar_rgb":
        warnings.warn(
            "no usable libLLVM found: tabulating with Mitsuba's scalar_rgb variant, which takes minutes "
            "instead of a second (install Debian's libllvm19, or set DRJIT_LIBLLVM_PATH)",
            RuntimeWarning,
            stacklevel=4,
        )
    try:
        yield mi
    finally:
        if previous is not None and previous != variant:
            mi.set_variant(previous)
