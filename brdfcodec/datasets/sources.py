"""Where dataset materials come from: MERL files, RGL files, NBRDF proxies, analytic BRDFs.

Each builder returns a list of :class:`MaterialSource`: the names are known
before anything heavy is read (the split needs them), and each table is
loaded only when the dataset writer asks for it. Every source names its
*family* — the measurement database the material belongs to (``"merl"``,
``"rgl"``, ``"analytic"``), whether the table is a measurement or a fit of
one — and its *source kind* — how the table was made (``"merl"``,
``"rgl-measured"``, ``"nbrdf-proxy"``, ``"analytic"``). Datasets record both
and hold out materials per family (:func:`brdfcodec.datasets.split.split_by_family`).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

from brdfcodec.datasets.analytic import ANALYTIC_PRESETS, AnalyticBRDF, random_analytic_materials
from brdfcodec.datasets.nbrdf import (
    NBRDF_SOURCE_KIND,
    is_nbrdf_weight_file,
    iter_nbrdf_zip,
    list_nbrdf_folder,
    list_nbrdf_zip,
    nbrdf_folder_family,
    nbrdf_zip_family,
    read_nbrdf_fit,
)
from brdfcodec.errors import SourceFormatError
from brdfcodec.io.file_kinds import describe_file_kind
from brdfcodec.io.genuine import genuine_merl_name
from brdfcodec.io.inputs import default_material_name, is_measured_file, read_measured
from brdfcodec.io.merl import MerlBRDF, read_merl, source_digest
from brdfcodec.io.rgl import RGL_SOURCE_KIND, is_rgl_file, read_rgl_bsdf

__all__ = [
    "ANALYTIC_SOURCE_KIND",
    "MERL_SOURCE_KIND",
    "LoadedMaterial",
    "MaterialSource",
    "analytic_sources",
    "input_sources",
    "measured_file_source",
    "merl_folder_sources",
    "nbrdf_sources",
    "nbrdf_zip_sources",
    "rgl_folder_sources",
]

_ZIP_SIGNATURES = (b"PK\x03\x04", b"PK\x05\x06")

MERL_SOURCE_KIND = "merl"
ANALYTIC_SOURCE_KIND = "analytic"


@dataclass(frozen=True)
class LoadedMaterial:
    """A material's table with its provenance.

    Attributes
    ----------
    brdf : MerlBRDF
        The table in stored MERL units.
    source_sha256 : str
        SHA-256 of the source bytes (MERL file, weight file, or parameters).
    genuine_merl : str
        Name of the genuine MERL file this is, or "" when it is not one.
    """

    brdf: MerlBRDF
    source_sha256: str
    genuine_merl: str = ""


@dataclass(frozen=True)
class MaterialSource:
    """A material that can be loaded on demand.

    Attributes
    ----------
    name : str
        Material name.
    origin : str
        Human-readable provenance (a file path, an archive member, parameters).
    load : callable
        Returns the :class:`LoadedMaterial`.
    family : str
        Measurement database the material belongs to: ``"merl"``, ``"rgl"``,
        ``"analytic"`` (or an archive's own name).
    source_kind : str
        How the table is made: ``"merl"``, ``"rgl-measured"``,
        ``"nbrdf-proxy"`` or ``"analytic"``.
    """

    name: str
    origin: str
    load: Callable[[], LoadedMaterial]
    family: str = MERL_SOURCE_KIND
    source_kind: str = MERL_SOURCE_KIND


def _folder_files(folder: str | os.PathLike[str], suffix: str, database: str) -> list[Path]:
    """The ``*.{suffix}`` files of a folder (not recursive), sorted; errors name the folder."""
    root = Path(folder)
    if not root.exists():
        raise FileNotFoundError(f"{root}: no such folder")
    if not root.is_dir():
        raise NotADirectoryError(f"{root}: is not a folder of {database} .{suffix} files")
    files = sorted(p for p in root.glob(f"*.{suffix}") if p.is_file())
    if not files:
        raise SourceFormatError(root, f"folder holds no {database} .{suffix} files")
    return files


def merl_folder_sources(folder: str | os.PathLike[str]) -> list[MaterialSource]:
    """Every ``*.binary`` file of a folder (not recursive), sorted by name.

    Raises
    ------
    NotADirectoryError, FileNotFoundError
        ``folder`` is not an existing folder.
    SourceFormatError
        The folder holds no ``.binary`` file.
    """
    files = _folder_files(folder, "binary", "MERL")

    def loader(path: Path) -> Callable[[], LoadedMaterial]:
        def load() -> LoadedMaterial:
            brdf = read_merl(path)
            return LoadedMaterial(brdf, brdf.sha256, genuine_merl_name(brdf.sha256) or "")

        return load

    return [MaterialSource(p.stem, str(p), loader(p), "merl", MERL_SOURCE_KIND) for p in files]


def rgl_folder_sources(folder: str | os.PathLike[str]) -> list[MaterialSource]:
    """Every RGL ``*.bsdf`` file of a folder (not recursive), sorted by name, tabulated when loaded.

    Material names drop the database's ``_rgb`` suffix (``paper_white_rgb.bsdf`` → ``paper_white``).

    Raises
    ------
    NotADirectoryError, FileNotFoundError
        ``folder`` is not an existing folder.
    SourceFormatError
        The folder holds no ``.bsdf`` file.
    """
    files = _folder_files(folder, "bsdf", "RGL")

    def loader(path: Path) -> Callable[[], LoadedMaterial]:
        def load() -> LoadedMaterial:
            brdf = read_rgl_bsdf(path)
            return LoadedMaterial(brdf, source_digest(brdf))

        return load

    return [MaterialSource(p.stem.removesuffix("_rgb"), str(p), loader(p), "rgl", RGL_SOURCE_KIND) for p in files]


def nbrdf_zip_sources(
    archive: str | os.PathLike[str], names: Iterable[str] | None = None
) -> list[MaterialSource]:
    """Materials of the NBRDF proxy archive, tabulated on the MERL grid when loaded.

    Parameters
    ----------
    archive : str or os.PathLike
        ``merl-nbrdf-90.zip``.
    names : iterable of str, optional
        A subset of materials; all by default.
    """
    available = list_nbrdf_zip(archive)
    family = nbrdf_zip_family(archive)
    chosen = available if names is None else list(names)
    unknown = sorted(set(chosen) - set(available))
    if unknown:
        raise SourceFormatError(archive, f"archive has no material named {', '.join(unknown)}")

    def loader(name: str) -> Callable[[], LoadedMaterial]:
        def load() -> LoadedMaterial:
            fit = next(iter_nbrdf_zip(archive, [name]))
            return LoadedMaterial(fit.to_merl(), fit.source_sha256)

        return load

    return [
        MaterialSource(n, f"{os.fspath(archive)}:{n}.h5 ({NBRDF_SOURCE_KIND})", loader(n), family, NBRDF_SOURCE_KIND)
        for n in chosen
    ]


def _is_zip(path: Path) -> bool:
    try:
        with open(path, "rb") as stream:
            return stream.read(4) in _ZIP_SIGNATURES
    except OSError:
        return False


def _fit_source(path: Path, family: str) -> MaterialSource:
    """One NBRDF weight file as a source (its ``.json`` beside it is checked when loaded)."""

    def load() -> LoadedMaterial:
        fit = read_nbrdf_fit(path)
        return LoadedMaterial(fit.to_merl(), fit.source_sha256)

    return MaterialSource(path.stem, f"{path} ({NBRDF_SOURCE_KIND})", load, family, NBRDF_SOURCE_KIND)


def nbrdf_sources(path: str | os.PathLike[str], names: Iterable[str] | None = None) -> list[MaterialSource]:
    """NBRDF fits in any of the forms they come in, tabulated on the MERL grid when loaded.

    Parameters
    ----------
    path : str or os.PathLike
        The published archive (``merl-nbrdf-90.zip``), the folder it unpacks
        to (``merl-nbrdf/``: ``NAME.h5`` weights with ``NAME.json``
        descriptions), or one fit's ``NAME.h5`` (or its ``NAME.json``, with
        the weights beside it). The family is the archive's or the folder's
        (:func:`~brdfcodec.datasets.nbrdf.nbrdf_zip_family`,
        :func:`~brdfcodec.datasets.nbrdf.nbrdf_folder_family`).
    names : iterable of str, optional
        A subset of materials; all by default.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    SourceFormatError
        Neither a zip archive, a folder nor an HDF5 file of NBRDF weights; a
        folder or archive without fits; a name it does not hold.
    """
    root = Path(path)
    if root.is_dir():
        files = list_nbrdf_folder(root)
        family = nbrdf_folder_family(root)
        available = {p.stem: p for p in files}
        chosen = list(available) if names is None else list(names)
        unknown = sorted(set(chosen) - set(available))
        if unknown:
            raise SourceFormatError(root, f"folder has no material named {', '.join(unknown)}")
        return [_fit_source(available[n], family) for n in chosen]
    if not root.exists():
        raise FileNotFoundError(f"{root}: no such file or folder")
    if _is_zip(root):
        return nbrdf_zip_sources(root, names)
    weights = _weights_beside(root) if root.suffix.lower() == ".json" else root
    if not is_nbrdf_weight_file(weights):
        kind = describe_file_kind(weights) or "a file of unknown kind"
        raise SourceFormatError(
            root, f"this is {kind}, not NBRDF fits: expected their zip archive (merl-nbrdf-90.zip), the folder it "
            "unpacks to, or one fit's NAME.h5 weights (with NAME.json beside it)"
        )
    source = _fit_source(weights, nbrdf_folder_family(weights.parent))
    if names is not None and list(names) != [source.name]:
        raise SourceFormatError(root, f"holds the one material {source.name!r}")
    return [source]


def _weights_beside(description: Path) -> Path:
    """The ``NAME.h5`` weights of an NBRDF fit's ``NAME.json`` description (a SourceFormatError when absent)."""
    weights = description.with_suffix(".h5")
    if not weights.is_file():
        raise SourceFormatError(
            description, f"an NBRDF fit's description needs its weights beside it, and {weights.name} is missing "
            "(the fit is the NAME.h5 file; the NAME.json only describes its network)"
        )
    return weights


def measured_file_source(path: str | os.PathLike[str]) -> MaterialSource:
    """One measured file — a MERL ``.binary`` or an RGL ``.bsdf``, told by content — as a source."""
    file_path = Path(path)
    name = default_material_name(file_path)
    rgl = is_rgl_file(file_path)

    def load() -> LoadedMaterial:
        brdf = read_measured(file_path, name=name)
        genuine = "" if rgl else genuine_merl_name(brdf.sha256) or ""
        return LoadedMaterial(brdf, source_digest(brdf), genuine)

    family, kind = ("rgl", RGL_SOURCE_KIND) if rgl else ("merl", MERL_SOURCE_KIND)
    return MaterialSource(name, str(file_path), load, family, kind)


def input_sources(path: str | os.PathLike[str]) -> list[MaterialSource]:
    """The materials one input path names, told by content: what ``bvae compress`` reads besides datasets.

    Parameters
    ----------
    path : str or os.PathLike
        A MERL ``.binary`` or RGL ``.bsdf`` file; an NBRDF fit (``NAME.h5``,
        or its ``NAME.json`` with the weights beside it); an NBRDF archive
        (``merl-nbrdf-90.zip``); or a folder of any of these files (not
        recursive: its ``.binary`` and ``.bsdf`` files and the ``.h5`` files
        that hold NBRDF weights, sorted by name). A brdfcodec dataset (an
        HDF5 file without NBRDF weights) is not a source of this kind.

    Returns
    -------
    list of MaterialSource
        In order: the files, or the folder's or archive's materials by name.

    Raises
    ------
    FileNotFoundError
        The path does not exist, or a folder holds none of these files.
    SourceFormatError
        A malformed archive or fit description.
    """
    root = Path(path)
    if root.is_dir():
        found = sorted(p for p in root.iterdir() if is_measured_file(p) or (p.suffix.lower() == ".h5"
                                                                           and is_nbrdf_weight_file(p)))
        if not found:
            below = sorted(p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")
                           and any(is_measured_file(f) or f.suffix.lower() == ".h5" for f in p.iterdir()))
            hint = f"; look in its subfolder {' or '.join(below)}" if below else ""
            raise FileNotFoundError(
                f"{root}: folder holds no MERL .binary, RGL .bsdf or NBRDF fit (NAME.h5 with NAME.json) file{hint}"
            )
        family = nbrdf_folder_family(root)
        return [_fit_source(p, family) if p.suffix.lower() == ".h5" else measured_file_source(p) for p in found]
    if not root.exists():
        raise FileNotFoundError(f"{root}: no such file or folder")
    if _is_zip(root):
        return nbrdf_zip_sources(root)
    if is_nbrdf_weight_file(root):
        return nbrdf_sources(root)
    if root.suffix.lower() == ".json" and (describe_file_kind(root) or "").startswith("a text file"):
        return nbrdf_sources(root)  # an NBRDF fit's description: its weights beside it, or an error naming them
    return [measured_file_source(root)]


def analytic_sources(
    presets: Iterable[str] | None = None, *, random_count: int = 0, seed: int = 0
) -> list[MaterialSource]:
    """Analytic Lambert + GGX materials: named presets and reproducible random ones.

    Parameters
    ----------
    presets : iterable of str, optional
        Names from :data:`~brdfcodec.datasets.analytic.ANALYTIC_PRESETS`; all by default.
    random_count : int, default 0
        Number of extra random materials (``analytic-NNN``).
    seed : int, default 0
        Seed of the random materials.
    """
    chosen = list(ANALYTIC_PRESETS) if presets is None else list(presets)
    unknown = [name for name in chosen if name not in ANALYTIC_PRESETS]
    if unknown:
        raise ValueError(f"unknown analytic preset(s) {unknown}; choose from {sorted(ANALYTIC_PRESETS)}")
    materials = [ANALYTIC_PRESETS[name] for name in chosen]
    materials += list(random_analytic_materials(random_count, seed=seed))

    def loader(material: AnalyticBRDF) -> Callable[[], LoadedMaterial]:
        def load() -> LoadedMaterial:
            digest = hashlib.sha256(_describe(material).encode()).hexdigest()
            return LoadedMaterial(material.to_merl(), digest)

        return load

    return [
        MaterialSource(m.name, _describe(m), loader(m), ANALYTIC_SOURCE_KIND, ANALYTIC_SOURCE_KIND)
        for m in materials
    ]


def _describe(material: AnalyticBRDF) -> str:
    return "analytic Lambert+GGX " + json.dumps(asdict(material), sort_keys=True)
