"""OpenEXR output: RGB images and φd slices of BRDF tables (through the OpenEXR package)."""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from brdfcodec.io.atomic import atomic_output

__all__ = ["SLICE_UNITS", "read_exr_rgb", "read_exr_attributes", "write_exr_rgb", "write_exr_slices"]

#: What every part of a φd-slice EXR holds, in its header (attribute ``brdfcodec_units``).
SLICE_UNITS = "reflectance 1/sr (MERL stored value x channel scale); 0 below the horizon and where unmeasured"


def _openexr():  # noqa: ANN202 - module object
    try:
        import OpenEXR
    except ImportError as error:  # pragma: no cover - a declared dependency
        raise ImportError("EXR output needs the OpenEXR package: pip install OpenEXR") from error
    return OpenEXR


def _header(openexr: object) -> dict[str, object]:
    return {"compression": openexr.ZIP_COMPRESSION, "type": openexr.scanlineimage}  # type: ignore[attr-defined]


def write_exr_rgb(path: str | os.PathLike[str], rgb: npt.ArrayLike, *, overwrite: bool = False) -> None:
    """Write an (H, W, 3) linear RGB image as a float32 EXR, atomically."""
    openexr = _openexr()
    image = np.ascontiguousarray(rgb, dtype=np.float32)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {image.shape}")
    with atomic_output(path, overwrite=overwrite) as tmp:
        openexr.File(_header(openexr), {"RGB": image}).write(str(tmp))


def write_exr_slices(
    path: str | os.PathLike[str],
    reflectance: npt.ArrayLike,
    phi_d_bins: Sequence[int],
    *,
    overwrite: bool = False,
) -> None:
    """Write φd slices of a table as a multi-part EXR, one 90×90 RGB part per bin.

    Each part's header names what it holds: ``brdfcodec_units`` (:data:`SLICE_UNITS`) and
    ``brdfcodec_phi_d_bin``.

    Parameters
    ----------
    path : str or os.PathLike
    reflectance : array_like, shape (3, 90, 90, K)
        Values to store (rows θh bins, columns θd bins), one slice per entry of
        ``phi_d_bins``.
    phi_d_bins : sequence of int
        The φd bin of each slice; part names are ``phid000`` … ``phid179``.
    """
    openexr = _openexr()
    table = np.asarray(reflectance, dtype=np.float32)
    if table.ndim != 4 or table.shape[0] != 3 or table.shape[3] != len(phi_d_bins):
        raise ValueError(f"expected shape (3, 90, 90, {len(phi_d_bins)}), got {table.shape}")
    parts = [
        openexr.Part({**_header(openexr), "brdfcodec_units": SLICE_UNITS, "brdfcodec_phi_d_bin": str(int(b))},
                     {"RGB": np.ascontiguousarray(np.moveaxis(table[..., k], 0, -1))}, f"phid{b:03d}")
        for k, b in enumerate(phi_d_bins)
    ]
    with atomic_output(path, overwrite=overwrite) as tmp:
        openexr.File(parts).write(str(tmp))


def read_exr_attributes(path: str | os.PathLike[str], name: str) -> dict[str, object]:
    """The header attribute ``name`` of every part of an EXR file, keyed by part name (None where absent)."""
    openexr = _openexr()
    with openexr.File(os.fspath(path)) as handle:
        return {part.name(): part.header.get(name) for part in handle.parts}


def read_exr_rgb(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Every part of an EXR file as (H, W, 3) float32 arrays keyed by part name (``""`` for single-part files)."""
    openexr = _openexr()
    with openexr.File(os.fspath(path)) as handle:
        return {part.name(): np.array(part.channels["RGB"].pixels, dtype=np.float32) for part in handle.parts}
