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
from brdfcodec.datasets.nbrdf import NBRDF_SOURCE_KIND, iter_nbrdf_zip, list_nbrdf_zip, nbrdf_zip_family
from brdfcodec.errors import SourceFormatError
from brdfcodec.io.genuine import genuine_merl_name
from brdfcodec.io.merl import MerlBRDF, read_merl, source_digest
from brdfcodec.io.rgl import RGL_SOURCE_KIND, read_rgl_bsdf

__all__ = [
    "ANALYTIC_SOURCE_KIND",
    "MERL_SOURCE_KIND",
    "LoadedMaterial",
    "MaterialSource",
    "analytic_sources",
    "merl_folder_sources",
    "nbrdf_zip_sources",
    "rgl_folder_sources",
]

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
