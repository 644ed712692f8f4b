"""Where models live: the ones shipped in the package, and folders users register.

Models are found by the SHA-256 of their decoder weights (the reference a
``.bvae`` file carries), never by a list position. Search order: folders
registered with :func:`register_model_folder` in this process, the folders
in ``$BRDFCODEC_MODEL_PATH`` (``os.pathsep``-separated; each a model folder
or a folder of model folders), then the models shipped in the package.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from brdfcodec.errors import DecoderNotFoundError
from brdfcodec.models.manifest import MANIFEST, ModelManifest, load_manifest

__all__ = [
    "DEFAULT_MODEL_NAME",
    "ModelNotFoundError",
    "available_models",
    "default_model_folder",
    "find_model",
    "register_model_folder",
]

#: Folder name (under ``brdfcodec/data/models``) of the model used when none is named.
DEFAULT_MODEL_NAME = "default"

_registered: list[Path] = []


class ModelNotFoundError(DecoderNotFoundError):
    """No known model has the requested decoder."""


def _package_models() -> Path:
    return Path(str(resources.files("brdfcodec").joinpath("data/models")))


def default_model_folder() -> Path:
    """Folder of the model shipped as the package default.

    Raises
    ------
    ModelNotFoundError
        The installation has no default model (a broken install).
    """
    folder = _package_models() / DEFAULT_MODEL_NAME
    if not (folder / MANIFEST).is_file():
        raise ModelNotFoundError(f"{folder}: the default model is missing; reinstall brdfcodec")
    return folder


def register_model_folder(folder: str | os.PathLike[str]) -> ModelManifest:
    """Make a user-trained model (a folder written by ``bvae model export``) findable by its decoder hash."""
    manifest = load_manifest(folder)
    path = Path(folder).resolve()
    if path not in _registered:
        _registered.insert(0, path)
    return manifest


def _candidate_folders() -> list[Path]:
    roots = list(_registered)
    roots += [Path(p) for p in os.environ.get("BRDFCODEC_MODEL_PATH", "").split(os.pathsep) if p]
    roots.append(_package_models())
    folders: list[Path] = []
    for root in roots:
        if (root / MANIFEST).is_file():
            folders.append(root)
        elif root.is_dir():
            folders += sorted(p for p in root.iterdir() if (p / MANIFEST).is_file())
    return folders


def available_models() -> list[ModelManifest]:
    """Every model that can be found, in search order."""
    return [load_manifest(folder) for folder in _candidate_folders()]


def find_model(decoder_sha256: str) -> ModelManifest:
    """The model whose decoder weights have this SHA-256.

    Raises
    ------
    ModelNotFoundError
        None has it; the message lists the hashes that are available.
    """
    wanted = decoder_sha256.lower()
    models = available_models()
    for manifest in models:
        if manifest.decoder_sha256 == wanted:
            return manifest
    known = ", ".join(f"{m.decoder_sha256} ({m.name})" for m in models) or "none"
    raise ModelNotFoundError(
        f"no decoder with SHA-256 {wanted}; available: {known}. Register the model folder that made the file "
        "(brdfcodec.models.registry.register_model_folder or $BRDFCODEC_MODEL_PATH)"
    )
