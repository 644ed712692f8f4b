"""Writing decoded tables: MERL ``.binary``, NumPy ``.npy``, EXR φd slices or RGL ``.bsdf``, chosen by file suffix."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_PHI_D, TABLE_SHAPE
from brdfcodec.io.atomic import atomic_output
from brdfcodec.io.merl import write_merl
from brdfcodec.representation import reflectance_from_stored

if TYPE_CHECKING:
    from brdfcodec.io.rgl_writer import RglResolution

__all__ = ["TABLE_FORMATS", "TableFormat", "table_format_of", "write_table"]

TableFormat = Literal["binary", "npy", "exr", "bsdf"]
TABLE_FORMATS: dict[str, TableFormat] = {".binary": "binary", ".npy": "npy", ".exr": "exr", ".bsdf": "bsdf"}


def table_format_of(path: str | os.PathLike[str]) -> TableFormat:
    """The output format a path's suffix asks for (``ValueError`` naming the choices otherwise)."""
    suffix = Path(path).suffix.lower()
    if suffix not in TABLE_FORMATS:
        raise ValueError(f"{path}: unknown output type {suffix or '(none)'}; use one of {', '.join(TABLE_FORMATS)}")
    return TABLE_FORMATS[suffix]


def write_table(
    path: str | os.PathLike[str],
    table: npt.ArrayLike,
    *,
    phi_d_bins: Sequence[int] | None = None,
    overwrite: bool = False,
    rgl_resolution: RglResolution | None = None,
    name: str | None = None,
) -> TableFormat:
    """Write a decoded table (stored MERL units) atomically, in the format the suffix names.

    Parameters
    ----------
    path : str or os.PathLike
        The unit follows the output type, on purpose: ``.binary``: a MERL file
        (needs all 180 bins), MERL's stored units. ``.npy``: the float32 array
        as given, shape (3, 90, 90, K), in the same stored MERL units (a
        ``.npy`` holds no metadata: it keeps the units of ``.binary`` and of
        :func:`brdfcodec.decompress`, and -1 where MERL marks "unmeasured").
        ``.exr`` (an image format, for viewers and renderers): one 90×90 RGB
        part per φd bin holding reflectance in 1/sr (stored × channel scale;
        negative, unmeasured entries written as 0), named in each part's
        header (:data:`brdfcodec.io.exr.SLICE_UNITS`). ``.bsdf``: an RGL tensor file for
        Mitsuba's ``measured`` BSDF (needs all 180 bins; see
        :func:`brdfcodec.io.rgl_writer.write_rgl_bsdf`).
    table : array_like, shape (3, 90, 90, K)
    phi_d_bins : sequence of int, optional
        The bins the table's last axis holds (all 180 when absent).
    overwrite : bool, default False
    rgl_resolution : RglResolution, optional
        Table sizes of a ``.bsdf`` file (the defaults of
        :class:`~brdfcodec.io.rgl_writer.RglResolution` when absent).
    name : str, optional
        Material name, for a ``.bsdf`` file's description (the file's stem when absent).
    """
    kind = table_format_of(path)
    array = np.asarray(table)
    bins = list(range(N_PHI_D)) if phi_d_bins is None else [int(b) for b in phi_d_bins]
    if array.shape != (*TABLE_SHAPE[:3], len(bins)):
        raise ValueError(f"table shape {array.shape} does not match {len(bins)} φd bins")
    if kind == "binary":
        if len(bins) != N_PHI_D or bins != list(range(N_PHI_D)):
            raise ValueError(f"{path}: a MERL .binary file needs all 180 φd bins; use .npy or .exr for a subset")
        write_merl(path, array.astype(np.float64), overwrite=overwrite)
    elif kind == "bsdf":
        if len(bins) != N_PHI_D or bins != list(range(N_PHI_D)):
            raise ValueError(f"{path}: an RGL .bsdf file needs all 180 φd bins; use .npy or .exr for a subset")
        from brdfcodec.io.rgl_writer import write_rgl_bsdf

        write_rgl_bsdf(path, array, name=name or Path(path).stem, resolution=rgl_resolution, overwrite=overwrite)
    elif kind == "npy":
        with atomic_output(path, overwrite=overwrite) as tmp, open(tmp, "wb") as stream:
            np.save(stream, np.ascontiguousarray(array, dtype=np.float32))
    else:
        from brdfcodec.io.exr import write_exr_slices

        reflectance = reflectance_from_stored(np.maximum(array, 0).astype(np.float64))
        write_exr_slices(path, reflectance, bins, overwrite=overwrite)
    return kind
