"""Where models live: the ones shipped in the package, and folders users register.

Models are found by the SHA-256 of their decoder weights (the reference a
``.bvae`` file carries), never by a list position. Search order: folders
registered in this process (a :class:`ModelRegistry`; the module-level
functions use the process's :func:`process_registry`), the folders
in ``$BRDFCODEC_MODEL_PATH`` (``os.pathsep``-separated; each a model folder
or a folder of model folders), the folders saved by ``bvae model register``
(one per line in ``model-folders.txt`` of the user configuration folder:
``$BRDFCODEC_CONFIG_DIR``, else ``$XDG_CONFIG_HOME/brdfcodec``, else
``~/.config/brdfcodec``), the folders of installed model packages (entry point group
``brdfcodec.models``: each names a function that returns a folder of model folders; the package
``brdfcodec-legacy-models`` holds the earlier defaults so), then the model shipped in the package (one: the
default).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from importlib import resources
from pathlib import Path

from brdfcodec.errors import BrdfcodecError, ModelNotFoundError
from brdfcodec.io.folder_files import read_folder_file
from brdfcodec.io.hashing import refers_to
from brdfcodec.models.manifest import MANIFEST, MAX_MANIFEST_BYTES, ModelManifest, load_manifest

__all__ = [
    "DEFAULT_MODEL_NAME",
    "ModelNotFoundError",
    "ModelRegistry",
    "process_registry",
    "unregister_model_folder",
    "available_models",
    "default_model_folder",
    "package_model_folder",
    "find_model",
    "find_model_named",
    "resolve_manifest",
    "config_file",
    "installed_model_folders",
    "register_model_folder",
    "save_model_folder",
    "saved_model_folders",
]

#: Folder name (under ``brdfcodec/data/models``) of the model used when none is named.
DEFAULT_MODEL_NAME = "default"
#: Entry point group under which installed packages name a function returning a folder of model folders.
MODEL_ENTRY_POINTS = "brdfcodec.models"
#: The package that holds the models the wheel no longer ships, and where it lies in a source tree.
LEGACY_PACKAGE = "brdfcodec-legacy-models"
LEGACY_SOURCE = "packages/brdfcodec-legacy-models"
#: Folder name of the opt-in editing model (issue 50), and where its package lies in a source tree.
EDITING_MODEL_NAME = "editing"
EDITING_MODEL_FULL_NAME = "bvae-nbrdf-proxy-edit-v1"
EDITING_SOURCE = "packages/brdfcodec-editing-model"
#: Earlier defaults, moved out of the wheel into :data:`LEGACY_PACKAGE`: decoder SHA-256 → model name.
RETIRED_MODELS = {
    "e1e3ed1e24dc5a8746abbfb9194725e1a9d02808c2e81125c64f3d9e37b39491": "bvae-nbrdf-proxy-small-v1",
    "cebebb8f40dec066843e927cab29f548ef4d93c235b4db8443738af086a2b794": "bvae-nbrdf-proxy-small-v2",
}



class ModelRegistry:
    """Model folders registered in this process, newest first (searched before the environment and the package).

    The folders are held as a tuple that each change replaces, so a search in
    progress never sees a half-made change.

    Examples
    --------
    >>> registry = ModelRegistry()
    >>> registry.folders
    ()
    """

    def __init__(self) -> None:
        self._folders: tuple[Path, ...] = ()

    @property
    def folders(self) -> tuple[Path, ...]:
        """Registered folders, the most recently registered first."""
        return self._folders

    def register(self, folder: str | os.PathLike[str]) -> ModelManifest:
        """Add a model folder (checked by loading its manifest); registering it again moves nothing."""
        manifest = load_manifest(folder)
        path = Path(folder).resolve()
        if path not in self._folders:
            self._folders = (path, *self._folders)
        return manifest

    def unregister(self, folder: str | os.PathLike[str]) -> None:
        """Remove a folder (no error if it was not registered)."""
        path = Path(folder).resolve()
        self._folders = tuple(p for p in self._folders if p != path)


_PROCESS_REGISTRY = ModelRegistry()


def process_registry() -> ModelRegistry:
    """The registry the module-level functions and :func:`find_model` search."""
    return _PROCESS_REGISTRY


def _package_models() -> Path:
    return Path(str(resources.files("brdfcodec").joinpath("data/models")))


def package_model_folder(name: str) -> Path:
    """Folder of a model by its folder name: ``"default"``, shipped in the package (``brdfcodec/data/models``),
    or an earlier default kept so that the files made with it still decode (``"nbrdf-proxy-small-v1"``,
    ``"nbrdf-proxy-small-v2"``), found among the searched folders (installed model packages first of all:
    ``brdfcodec-legacy-models`` holds these two).

    Raises
    ------
    ModelNotFoundError
        No folder of that name is found; for an earlier default the message names what to install.
    """
    folder = _package_models() / name
    if (folder / MANIFEST).is_file():
        return folder
    for candidate in _candidate_folders():
        if candidate.name == name:
            return candidate
    if name in {retired.removeprefix("bvae-") for retired in RETIRED_MODELS.values()}:
        raise ModelNotFoundError(f"model {name!r} is no longer in the brdfcodec wheel; {_legacy_remedy()}")
    shipped = sorted(p.name for p in _package_models().iterdir() if (p / MANIFEST).is_file())
    raise ModelNotFoundError(f"{folder}: the package ships no model {name!r} (it ships {', '.join(shipped)})")


def _legacy_remedy() -> str:
    return (f"install the package that holds the earlier defaults, {LEGACY_PACKAGE} (from a brdfcodec source "
            f"tree: pip install {LEGACY_SOURCE}), or set BRDFCODEC_MODEL_PATH to a folder that holds its model "
            f"folders ({LEGACY_SOURCE}/brdfcodec_legacy_models/models, or a copy of it)")


def installed_model_folders() -> list[Path]:
    """Folders of model folders named by installed packages (entry point group :data:`MODEL_ENTRY_POINTS`).

    A package whose entry point cannot be loaded, or does not return a folder, is skipped with a warning.
    """
    from importlib.metadata import entry_points

    roots = []
    for point in entry_points(group=MODEL_ENTRY_POINTS):
        try:
            provided = point.load()
            root = Path(provided() if callable(provided) else provided)
        except Exception as error:  # noqa: BLE001 - another package's failure breaks no model of this one
            warnings.warn(f"model package {point.value!r} skipped: {type(error).__name__}: {error}", stacklevel=2)
            continue
        roots.append(root)
    return roots


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
    return _PROCESS_REGISTRY.register(folder)


def unregister_model_folder(folder: str | os.PathLike[str]) -> None:
    """Undo :func:`register_model_folder` for this process."""
    _PROCESS_REGISTRY.unregister(folder)


def config_file() -> Path:
    """The user's list of registered model folders (may not exist)."""
    explicit = os.environ.get("BRDFCODEC_CONFIG_DIR")
    if explicit:
        return Path(explicit) / "model-folders.txt"
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "brdfcodec" / "model-folders.txt"


def saved_model_folders() -> list[Path]:
    """Folders saved by :func:`save_model_folder`, in the order saved."""
    path = config_file()
    if not path.is_file():
        return []
    return [Path(line.strip()) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def save_model_folder(folder: str | os.PathLike[str]) -> ModelManifest:
    """Register a model folder for every later process (written to :func:`config_file`)."""
    manifest = load_manifest(folder)
    resolved = Path(folder).resolve()
    known = saved_model_folders()
    if resolved not in known:
        path = config_file()
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("".join(f"{p}\n" for p in [*known, resolved]), encoding="utf-8")
    return manifest


def _candidate_folders() -> list[Path]:
    """Every folder holding a ``model.json``, in search order (unreadable search folders are passed over)."""
    roots = list(_PROCESS_REGISTRY.folders)
    roots += [Path(p) for p in os.environ.get("BRDFCODEC_MODEL_PATH", "").split(os.pathsep) if p]
    roots += saved_model_folders()
    roots += installed_model_folders()
    roots.append(_package_models())
    folders: list[Path] = []
    for root in roots:
        try:
            if (root / MANIFEST).is_file():
                folders.append(root)
            elif root.is_dir():
                folders += sorted(p for p in root.iterdir() if (p / MANIFEST).is_file())
        except OSError as error:  # a search folder that cannot be listed: like one that holds no model
            warnings.warn(f"{root}: model folder search skips it ({error.strerror or error})", stacklevel=3)
    return folders


def _usable_models() -> Iterator[ModelManifest | tuple[Path, BrdfcodecError]]:
    """Each findable model's manifest in search order, or, for a folder whose ``model.json`` is invalid, the
    folder and its error."""
    for folder in _candidate_folders():
        try:
            yield load_manifest(folder)
        except BrdfcodecError as error:
            yield folder, error


def _skip(folder: Path, error: BrdfcodecError) -> None:
    warnings.warn(f"{folder}: skipped, not a usable model folder ({error})", stacklevel=3)


def available_models() -> list[ModelManifest]:
    """Every model that can be found, in search order; a folder whose ``model.json`` is invalid is skipped with
    a warning (it breaks no other model)."""
    models = []
    for found in _usable_models():
        if isinstance(found, ModelManifest):
            models.append(found)
        else:
            _skip(*found)
    return models


def _names_hash(folder: Path, wanted: str) -> bool:
    """Whether an invalid folder's ``model.json`` still names ``wanted`` as its decoder hash (a quick look at a
    bounded regular file, so that the folder's own error is reported when it is the one a file needs)."""
    try:
        text = read_folder_file(folder, MANIFEST, limit=MAX_MANIFEST_BYTES)
    except BrdfcodecError:
        return False
    return f'"{wanted}'.encode() in text if len(wanted) < 64 else f'"{wanted}"'.encode() in text


def resolve_manifest(model: str | os.PathLike[str] | None) -> ModelManifest:
    """A model's manifest from what a user gives (``--model``); needs no torch (the command line checks a model's
    limits before it loads one).

    Parameters
    ----------
    model : str, path-like or None
        In this order: ``None``, the shipped default; a folder holding a ``model.json``; a decoder SHA-256 (64 hex
        digits, or the first 16 that a file with short references names, format 2.6); a name of one path part
        (:func:`find_model_named`: ``"editing"``, ``"default"``, ``"bvae-nbrdf-proxy-edit-v1"``); else a folder,
        refused if it is not a model folder. A name that no model has, but that is something on disk, is read as
        that folder (whose error is then raised).

    Returns
    -------
    ModelManifest

    Raises
    ------
    ModelNotFoundError
        An empty string, or a hash or a name that no findable model has (the message lists those there are).
    ModelFolderError
        A path that is not a valid model folder.
    """
    if model is None:
        return load_manifest(default_model_folder())
    text = os.fspath(model)
    if not text:
        raise ModelNotFoundError("an empty model reference: give a model folder, a decoder SHA-256 or a model name")
    path = Path(text)
    if (path / MANIFEST).is_file():
        return load_manifest(path)
    if len(text) in (16, 64) and all(c in "0123456789abcdef" for c in text.lower()) and not path.exists():
        return find_model(text)
    separators = {"/", os.sep, os.altsep} - {None}
    if len(path.parts) == 1 and not path.anchor and text != ".." and not any(sep in text for sep in separators):
        try:
            return find_model_named(text)
        except ModelNotFoundError:
            if not path.exists():
                raise
    return load_manifest(path)


def find_model_named(name: str) -> ModelManifest:
    """A findable model by name: ``"default"`` is the model shipped in the package; any other name is the first
    model, in search order, whose folder is named so (``"editing"``) or whose ``model.json`` names it so
    (``"bvae-nbrdf-proxy-edit-v1"``).

    A folder whose ``model.json`` is invalid is skipped with a warning, as :func:`find_model` does.

    Parameters
    ----------
    name : str
        A folder name or a model name.

    Returns
    -------
    ModelManifest

    Raises
    ------
    ModelNotFoundError
        No findable model has that name (the message lists the names there are, and how the editing model and
        the earlier defaults are installed).
    """
    if name == DEFAULT_MODEL_NAME:
        return load_manifest(default_model_folder())
    names: list[str] = []
    for found in _usable_models():
        if not isinstance(found, ModelManifest):
            _skip(*found)
            continue
        if name in (found.folder.name, found.name):
            return found
        names.append(f"{found.folder.name} ({found.name})")
    hints = []
    if name in (EDITING_MODEL_NAME, EDITING_MODEL_FULL_NAME):
        hints.append(f"the opt-in editing model is a package of its own: pip install {EDITING_SOURCE} (from a "
                     f"brdfcodec source tree), or set BRDFCODEC_MODEL_PATH to "
                     f"{EDITING_SOURCE}/brdfcodec_editing_model/models")
    if name in {retired.removeprefix("bvae-") for retired in RETIRED_MODELS.values()} | set(RETIRED_MODELS.values()):
        hints.append(_legacy_remedy())
    raise ModelNotFoundError(
        f"no model named {name!r} is installed (models found: {', '.join(names) or 'none'})"
        + ("; " + "; ".join(hints) if hints else "; give a model folder, a decoder SHA-256 or one of those names")
    )


def find_model(decoder_sha256: str) -> ModelManifest:
    """The model whose decoder weights have this SHA-256 (64 hex digits), or whose SHA-256 starts with these 16
    (a short reference, format 2.6: ``spec/bvae-format.md`` §3.1).

    Folders are searched in order and the first valid match wins; a folder whose ``model.json`` is invalid is
    skipped with a warning, and its error is raised only when no valid folder has the hash and it names it. A
    short reference is looked for in every folder (two decoders it names are refused, not chosen between), so
    every invalid folder's warning is given then.

    Raises
    ------
    ModelNotFoundError
        None has it (the message lists the hashes that are available), or a short reference names two decoders.
    ModelFolderError
        No valid folder has the hash, and an invalid one names it.
    """
    wanted = decoder_sha256.lower()
    models: list[ModelManifest] = []
    matches: list[ModelManifest] = []
    claimed: BrdfcodecError | None = None
    for found in _usable_models():
        if isinstance(found, ModelManifest):
            if refers_to(wanted, found.decoder_sha256):
                if len(wanted) == 64:
                    return found
                matches.append(found)  # a short reference: every folder is looked at, so that two are refused
            models.append(found)
            continue
        _skip(*found)
        if claimed is None and _names_hash(found[0], wanted):
            claimed = found[1]
    named = {m.decoder_sha256 for m in matches}
    if len(named) > 1:
        raise ModelNotFoundError(
            f"the short decoder reference {wanted} (the first 8 bytes of a SHA-256) names {len(named)} installed "
            f"decoders: {', '.join(f'{m.decoder_sha256} ({m.name})' for m in matches)}; keep only the model that "
            "made the file registered"
        )
    if matches:
        return matches[0]
    if claimed is not None:
        raise claimed
    retired = [sha for sha in RETIRED_MODELS if refers_to(wanted, sha)]
    if retired:
        raise ModelNotFoundError(
            f"decoder {wanted} is that of {RETIRED_MODELS[retired[0]]}, an earlier default no longer in the brdfcodec "
            f"wheel: {_legacy_remedy()}"
        )
    known = ", ".join(f"{m.decoder_sha256} ({m.name})" for m in models) or "none"
    raise ModelNotFoundError(
        f"no decoder with SHA-256 {wanted}; available: {known}. Register the model folder that made the file "
        "(bvae model register FOLDER, $BRDFCODEC_MODEL_PATH, or brdfcodec.models.registry.register_model_folder)"
    )
