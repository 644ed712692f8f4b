"""Reading any measured-BRDF file brdfcodec accepts, by its content.

Two formats are accepted wherever a measured material is read (``bvae
compress``, ``bvae info``, ``bvae dataset build``, :func:`brdfcodec.compress`):

- MERL ``.binary`` tables, read as they are (:func:`brdfcodec.io.merl.read_merl`);
- RGL ``.bsdf`` measurements (isotropic, RGB), tabulated on the MERL grid with
  Mitsuba 3's ``measured`` plugin (:func:`brdfcodec.io.rgl.read_rgl_bsdf`;
  optional extra ``brdfcodec[rgl]``).

The format is told by the file's first bytes, not its name, so a renamed file
is still read correctly.

NBRDF fits (``NAME.h5`` weights, their zip or folder), which ``bvae compress``
also reads, are networks rather than tables: they are evaluated on the MERL
grid one layer up, by :func:`brdfcodec.datasets.sources.input_sources`.
"""

from __future__ import annotations

import os
from pathlib import Path

from brdfcodec.io.merl import MerlBRDF, read_merl
from brdfcodec.io.rgl import is_rgl_file, read_rgl_bsdf

__all__ = ["MEASURED_SUFFIXES", "default_material_name", "is_measured_file", "read_measured"]

#: File suffixes of the measured formats, for picking files out of a folder.
MEASURED_SUFFIXES = (".binary", ".bsdf")


def is_measured_file(path: str | os.PathLike[str]) -> bool:
    """Whether a folder entry looks like a measured-BRDF file (by suffix; for listing folders)."""
    candidate = Path(path)
    return candidate.suffix.lower() in MEASURED_SUFFIXES and candidate.is_file()


def default_material_name(path: str | os.PathLike[str]) -> str:
    """A material's name from its file name: the stem, without the RGL database's ``_rgb`` suffix."""
    candidate = Path(path)
    if candidate.suffix.lower() == ".bsdf":
        return candidate.stem.removesuffix("_rgb")
    return candidate.stem


def read_measured(path: str | os.PathLike[str], *, name: str | None = None) -> MerlBRDF:
    """Read a MERL ``.binary`` file or tabulate an RGL ``.bsdf`` file on the MERL grid.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    name : str, optional
        Material name; by default the file's stem (without ``_rgb`` for RGL files).

    Returns
    -------
    MerlBRDF
        Stored MERL units, shape (3, 90, 90, 180).

    Raises
    ------
    MerlFormatError, SourceFormatError
        The file is neither, or is a broken or unsupported one of them.
    OptionalDependencyError
        An RGL file and Mitsuba 3 is not installed.
    """
    label = name or default_material_name(path)
    if is_rgl_file(path):
        return read_rgl_bsdf(path, name=label)
    return read_merl(path, name=label)
