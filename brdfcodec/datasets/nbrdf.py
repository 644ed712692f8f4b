"""The NBRDF proxy: neural fits of MERL materials evaluated on the MERL grid.

The fits (Sztrajman et al., "Neural BRDF Representation and Importance
Sampling", CGF 2021; MIT licence) are one small MLP per material,
``6 → 21 (ReLU) → 21 (ReLU) → 3 → exp(x) − 1``, whose input is the half
vector h and difference vector d (frame with φh = 0) and whose output is
physical reflectance (1/sr). Tabulated on the MERL grid they stand in for
measured MERL tables in development and CI. They are **not** MERL: every
dataset and report built from them says so (``source_kind = "nbrdf-proxy"``).

Conventions of the tabulation (``spec/conventions.md`` §9): angles are the
bins' representative angles; entries below the horizon are unmeasured; fit
outputs below 0 above the horizon (small undershoots of near-black values)
are clamped to 0 and stay valid.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import h5py
import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import UNMEASURED_VALUE
from brdfcodec.errors import SourceFormatError
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.representation import stored_from_reflectance
from brdfcodec.representation.coords import grid_angles
from brdfcodec.representation.mask import horizon_mask

__all__ = [
    "NBRDF_SOURCE_KIND",
    "NbrdfFit",
    "check_nbrdf_description",
    "is_nbrdf_weight_file",
    "iter_nbrdf_zip",
    "list_nbrdf_folder",
    "list_nbrdf_zip",
    "nbrdf_folder_family",
    "nbrdf_zip_family",
    "read_nbrdf_fit",
]

#: ``source_kind`` of datasets built from these fits.
NBRDF_SOURCE_KIND = "nbrdf-proxy"

_LAYERS = ("dense_1", "dense_2", "dense_3")
_LAYER_SHAPES = ((6, 21), (21, 21), (21, 3))
_ACTIVATIONS = ("relu", "relu", "linear")
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


@dataclass(frozen=True)
class NbrdfFit:
    """Weights of one NBRDF fit.

    Attributes
    ----------
    name : str
        Material name.
    kernels : tuple of ndarray
        Float32 kernels of shapes (6, 21), (21, 21), (21, 3); ``y = x · W + b``.
    biases : tuple of ndarray
        Float32 biases of lengths 21, 21, 3.
    source_sha256 : str
        SHA-256 of the weight file's bytes.
    """

    name: str
    kernels: tuple[np.ndarray, np.ndarray, np.ndarray]
    biases: tuple[np.ndarray, np.ndarray, np.ndarray]
    source_sha256: str = ""

    def evaluate_vectors(self, half: npt.ArrayLike, diff: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Raw network output (1/sr) for half and difference unit vectors, shape (..., 3)."""
        x = np.concatenate([np.asarray(half, np.float32), np.asarray(diff, np.float32)], axis=-1)
        for layer, (kernel, bias) in enumerate(zip(self.kernels, self.biases, strict=False)):
            x = x @ kernel + bias
            if layer < 2:
                np.maximum(x, 0, out=x)
        return np.expm1(x)

    def to_merl(self) -> MerlBRDF:
        """Tabulate on the MERL grid, as a MERL table in stored units.

        Returns
        -------
        MerlBRDF
            Below-horizon entries hold
            :data:`~brdfcodec.conventions.UNMEASURED_VALUE`; negative fit
            outputs above the horizon are clamped to 0. ``source_kind`` is
            ``"nbrdf-proxy"`` and ``source_sha256`` the weight file's, so that
            a record encoded from it names the fit it came from.
        """
        theta_h, theta_d, phi_d = grid_angles()
        zeros = np.zeros_like(theta_h)
        half = np.stack([np.sin(theta_h), zeros, np.cos(theta_h)], axis=-1)
        diff = np.stack(
            [np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], axis=-1
        )
        reflectance = np.moveaxis(self.evaluate_vectors(half, diff).astype(np.float64), -1, 0)
        stored = stored_from_reflectance(np.maximum(reflectance, 0.0))
        stored = np.where(horizon_mask()[None], stored, UNMEASURED_VALUE)
        if not np.isfinite(stored).all():
            raise SourceFormatError(self.name, "the fit produces non-finite values on the MERL grid")
        return MerlBRDF(
            np.ascontiguousarray(stored), name=self.name, source_kind=NBRDF_SOURCE_KIND,
            source_sha256=self.source_sha256 or None,
        )


def _read_weights(content: bytes, name: str, source: str) -> NbrdfFit:
    try:
        with h5py.File(io.BytesIO(content), "r") as handle:
            return _weights_from_handle(handle, name, source, hashlib.sha256(content).hexdigest())
    except OSError as error:
        raise SourceFormatError(source, f"not a readable HDF5 weight file ({error})") from None


def _weights_from_handle(handle: h5py.File, name: str, source: str, digest: str) -> NbrdfFit:
    kernels, biases = [], []
    for layer, shape in zip(_LAYERS, _LAYER_SHAPES, strict=False):
        try:
            kernel = np.asarray(handle[f"{layer}/{layer}/kernel:0"], dtype=np.float32)
            bias = np.asarray(handle[f"{layer}/{layer}/bias:0"], dtype=np.float32)
        except KeyError as error:
            raise SourceFormatError(source, f"NBRDF weights lack layer {layer!r} ({error})") from None
        if kernel.shape != shape or bias.shape != (shape[1],):
            raise SourceFormatError(
                source,
                f"layer {layer} has kernel {kernel.shape} and bias {bias.shape}, expected {shape} and ({shape[1]},)",
            )
        if not (np.isfinite(kernel).all() and np.isfinite(bias).all()):
            raise SourceFormatError(source, f"layer {layer} holds NaN or infinite weights")
        kernels.append(kernel)
        biases.append(bias)
    return NbrdfFit(name, tuple(kernels), tuple(biases), digest)  # type: ignore[arg-type]


def check_nbrdf_description(content: bytes, source: str | os.PathLike[str]) -> None:
    """Check a fit's Keras model description (``NAME.json``) against the network brdfcodec evaluates.

    The description must list, in order, Dense layers ``dense_1`` (21 units,
    ReLU), ``dense_2`` (21, ReLU) and ``dense_3`` (3, linear), then at most
    one Lambda layer (the published fits' ``exp(x) − 1``; its serialised code
    is never run, brdfcodec applies ``expm1`` itself).

    Parameters
    ----------
    content : bytes
        The ``.json`` file's bytes.
    source : str or os.PathLike
        The file, for messages.

    Raises
    ------
    SourceFormatError
        Not JSON, or another architecture.
    """
    try:
        description = json.loads(content)
        config = description["config"]
        layers = config["layers"] if isinstance(config, dict) else config
        found = [(layer["class_name"], layer["config"].get("name"), layer["config"].get("units"),
                  layer["config"].get("activation")) for layer in layers]
    except (ValueError, KeyError, TypeError, AttributeError) as error:
        raise SourceFormatError(source, f"not a Keras model description of an NBRDF fit ({error!r})") from None
    expected = [("Dense", name, shape[1], activation)
                for name, shape, activation in zip(_LAYERS, _LAYER_SHAPES, _ACTIVATIONS, strict=True)]
    tail = found[len(expected):]
    if found[: len(expected)] != expected or len(tail) > 1 or any(layer[0] != "Lambda" for layer in tail):
        raise SourceFormatError(
            source, f"describes layers {found}, not the NBRDF network {expected} followed by exp(x) - 1"
        )


def read_nbrdf_fit(path: str | os.PathLike[str], *, name: str | None = None) -> NbrdfFit:
    """Read one fit from its Keras ``NAME.h5`` weight file (and check its ``NAME.json`` when it lies beside it).

    The weights alone define the fit (the architecture is fixed, and their
    shapes are checked); the description, when present, must describe that
    architecture (:func:`check_nbrdf_description`).

    Raises
    ------
    SourceFormatError
        Not an HDF5 file, or not the NBRDF architecture.
    FileNotFoundError, IsADirectoryError
        ``path`` is not a file.
    """
    source = Path(path)
    content = source.read_bytes()  # OSError names the file
    description = source.with_suffix(".json")
    if description.is_file():
        check_nbrdf_description(description.read_bytes(), description)
    return _read_weights(content, name or source.stem, str(source))


def is_nbrdf_weight_file(path: str | os.PathLike[str]) -> bool:
    """Whether a file is an HDF5 file holding NBRDF weights (``dense_1/dense_1/kernel:0``); False for other files.

    Cheap: reads the signature, then opens HDF5 files to look for the first layer.
    """
    try:
        with open(path, "rb") as stream:
            if stream.read(len(_HDF5_SIGNATURE)) != _HDF5_SIGNATURE:
                return False
        with h5py.File(path, "r") as handle:
            return f"{_LAYERS[0]}/{_LAYERS[0]}/kernel:0" in handle
    except OSError:
        return False


def list_nbrdf_folder(folder: str | os.PathLike[str]) -> list[Path]:
    """The weight files (``*.h5``) of an unpacked NBRDF archive's folder, sorted by name (not recursive).

    Raises
    ------
    FileNotFoundError, NotADirectoryError
        ``folder`` is not an existing folder.
    SourceFormatError
        The folder holds no ``.h5`` file.
    """
    root = Path(folder)
    if not root.exists():
        raise FileNotFoundError(f"{root}: no such folder")
    if not root.is_dir():
        raise NotADirectoryError(f"{root}: is not a folder of NBRDF fits (NAME.h5 with NAME.json)")
    files = sorted(p for p in root.glob("*.h5") if p.is_file() and not p.name.startswith("."))
    if not files:
        below = sorted(p.name for p in root.iterdir() if p.is_dir() and any(p.glob("*.h5")))
        hint = f"; look in its subfolder {' or '.join(below)}" if below else ""
        raise SourceFormatError(root, f"folder holds no NBRDF weight files (*.h5){hint}")
    return files


def nbrdf_folder_family(folder: str | os.PathLike[str]) -> str:
    """Measurement family of a folder of NBRDF fits: its name without ``-nbrdf`` (``merl-nbrdf/`` → ``"merl"``).

    The unpacked published archives keep their fits in ``merl-nbrdf/`` and
    ``rgl-nbrdf/``, so a folder gives the family its archive gives
    (:func:`nbrdf_zip_family`).
    """
    return Path(os.path.abspath(folder)).name.split("-nbrdf")[0]


def list_nbrdf_zip(path: str | os.PathLike[str]) -> list[str]:
    """Material names in an NBRDF archive (``*.h5`` members), sorted.

    Raises
    ------
    SourceFormatError
        Not a zip archive, or one without any ``.h5`` member.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            names = sorted(
                PurePosixPath(member).stem
                for member in archive.namelist()
                if member.endswith(".h5") and not PurePosixPath(member).name.startswith(".")
            )
    except zipfile.BadZipFile as error:
        raise SourceFormatError(path, f"not a zip archive ({error})") from None
    if not names:
        raise SourceFormatError(path, "archive holds no NBRDF weight files (*.h5)")
    if len(set(names)) != len(names):
        raise SourceFormatError(path, "archive holds two weight files of the same material name")
    return names


def nbrdf_zip_family(path: str | os.PathLike[str]) -> str:
    """Measurement family of an NBRDF archive: the database its fits were made of.

    The published archives keep their members in one folder named after the
    database (``merl-nbrdf/``, ``rgl-nbrdf/``); the family is that folder's
    name without ``-nbrdf`` (``"merl"``, ``"rgl"``). An archive laid out
    otherwise takes the archive's file name instead (``"my-fits"`` for
    ``my-fits.zip``).

    Raises
    ------
    SourceFormatError
        Not a zip archive.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            folders = {
                PurePosixPath(member).parts[0]
                for member in archive.namelist()
                if member.endswith(".h5") and len(PurePosixPath(member).parts) > 1
            }
    except zipfile.BadZipFile as error:
        raise SourceFormatError(path, f"not a zip archive ({error})") from None
    if len(folders) == 1:
        return folders.pop().removesuffix("-nbrdf")
    return Path(path).stem.split("-nbrdf")[0]


def iter_nbrdf_zip(path: str | os.PathLike[str], names: list[str] | None = None) -> Iterator[NbrdfFit]:
    """Read fits from an NBRDF archive without unpacking it to disk.

    Parameters
    ----------
    path : str or os.PathLike
        The zip archive (``merl-nbrdf-90.zip``).
    names : list of str, optional
        Materials to read, in this order; all, sorted by name, by default.

    Yields
    ------
    NbrdfFit
    """
    wanted = list_nbrdf_zip(path) if names is None else list(names)
    with zipfile.ZipFile(path) as archive:
        members = {PurePosixPath(m).stem: m for m in archive.namelist() if m.endswith(".h5")}
        for name in wanted:
            if name not in members:
                raise SourceFormatError(path, f"archive has no material {name!r}")
            source = f"{os.fspath(path)}:{members[name]}"
            description = str(PurePosixPath(members[name]).with_suffix(".json"))
            if description in archive.namelist():
                check_nbrdf_description(archive.read(description), f"{os.fspath(path)}:{description}")
            yield _read_weights(archive.read(members[name]), name, source)
