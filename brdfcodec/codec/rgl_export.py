"""Materials of a ``.bvae`` library, or a measured file, written as RGL ``.bsdf`` files.

The workflow behind ``bvae decompress LIB.bvae -o OUT.bsdf``: decode with the
codec, then write with :mod:`brdfcodec.io.rgl_writer` (which knows nothing of
the codec).
"""

from __future__ import annotations

import os
from pathlib import Path

from brdfcodec.codec.library import MaterialLibrary
from brdfcodec.format.material_names import material_file_path
from brdfcodec.io.atomic import check_output_path
from brdfcodec.io.inputs import read_measured
from brdfcodec.io.rgl import is_rgl_file
from brdfcodec.io.rgl_writer import RglResolution, write_rgl_bsdf

__all__ = ["export_rgl"]


def export_rgl(
    source: str | os.PathLike[str],
    output: str | os.PathLike[str],
    *,
    materials: list[str] | None = None,
    resolution: RglResolution | None = None,
    overwrite: bool = False,
) -> list[Path]:
    """Write materials of a ``.bvae`` library, or a measured file, as RGL ``.bsdf`` files.

    The library call behind ``bvae decompress LIB.bvae -o OUT.bsdf`` and
    ``bvae decompress LIB.bvae -o FOLDER --format bsdf``.

    Parameters
    ----------
    source : str or os.PathLike
        A ``.bvae`` file (decoded with the model it names), a MERL ``.binary``
        file or an RGL ``.bsdf`` file (tabulated on the MERL grid first).
    output : str or os.PathLike
        The ``.bsdf`` file for a single material; for several, a folder (created
        if absent) that receives ``NAME.bsdf`` for each.
    materials : list of str, optional
        Materials of a library to write (all by default).
    resolution : RglResolution, optional
        Table sizes (:class:`RglResolution`'s defaults when absent).
    overwrite : bool, default False
        Whether existing files may be replaced.

    Returns
    -------
    list of pathlib.Path
        The written files.

    Raises
    ------
    RglWriteError
        A material is non-finite, unmeasured or black (files written before it stay; none is partial).
    SourceFormatError, MerlFormatError, BvaeFormatError
        The source is unreadable or unsupported (an anisotropic or spectral RGL file, say); nothing is written.
    FileExistsError
        A target exists and ``overwrite`` is false; nothing is written.
    """

    src, out = Path(source), Path(output)
    if is_rgl_file(src) or src.suffix.lower() == ".binary":

        if materials:
            raise ValueError(f"{src}: a measured file holds one material; 'materials' applies to .bvae libraries")
        brdf = read_measured(src)
        label = brdf.name or src.stem
        target = material_file_path(out, label, "bsdf") if out.is_dir() else out
        return [write_rgl_bsdf(target, brdf.values, name=label, resolution=resolution, overwrite=overwrite)]

    with MaterialLibrary(src) as library:
        names = list(materials) if materials else library.names
        for name in names:
            library.record(name)  # unknown names and corrupt records fail before anything is written
        if len(names) == 1 and not out.is_dir():
            targets = {names[0]: check_output_path(out, overwrite=overwrite)}
        else:
            if out.exists() and not out.is_dir():
                raise NotADirectoryError(f"{out}: several materials need an output folder, not a file")
            paths = {name: material_file_path(out, name, "bsdf") for name in names}
            out.mkdir(parents=True, exist_ok=True)
            targets = {name: check_output_path(path, overwrite=overwrite) for name, path in paths.items()}
        written = []
        for name, target in targets.items():
            table = library[name].table()
            written.append(write_rgl_bsdf(target, table, name=name, resolution=resolution, overwrite=overwrite))
            library.forget(name)
        return written
