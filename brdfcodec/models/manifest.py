"""Model manifests (``model.json``): what a model folder holds, read without importing torch."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from brdfcodec.errors import ModelFolderError
from brdfcodec.io.folder_files import read_folder_file
from brdfcodec.io.hashing import is_sha256_hex
from brdfcodec.models.config import ModelConfig

__all__ = [
    "DECODER_FILE",
    "ENCODER_FILE",
    "MANIFEST",
    "MAX_MANIFEST_BYTES",
    "ModelFolderError",
    "ModelManifest",
    "load_manifest",
    "parse_manifest",
]

MANIFEST = "model.json"
ENCODER_FILE = "encoder.safetensors"
DECODER_FILE = "decoder.safetensors"


@dataclass(frozen=True)
class ModelManifest:
    """What ``model.json`` says of a model.

    Attributes
    ----------
    name : str
        Readable name, e.g. ``"bvae-nbrdf-proxy-small-v1"``.
    config : ModelConfig
        Architecture.
    decoder_sha256, encoder_sha256 : str
        Hex SHA-256 of the weight files.
    folder : pathlib.Path
        Where the files are.
    info : dict
        Training facts (data, split, schedule, metrics), free-form.
    parameters : dict
        What each latent dimension controls (named parameters, colour dimensions).
    basis_sha256 : str or None
        Hex SHA-256 of the shared basis file (``basis.safetensors``), when the model has one: the basis
        encoders use.
    encoder_storage : {"full", "compact"}
        How ``encoder.safetensors`` stores the encoder (``spec/model.md`` §3): every tensor as trained, or
        large matrices as float16 and the linear path derived from the decoder's basis.
    basis_prefixes : dict of str to int
        Earlier bases this model's basis extends (``spec/model.md`` §5): SHA-256 of such a basis file → its
        vector count, the basis' leading vectors being exactly that file's. Files whose basis layers name one
        of them decode with this model.
    """

    name: str
    config: ModelConfig
    decoder_sha256: str
    encoder_sha256: str
    folder: Path
    info: dict[str, Any]
    parameters: dict[str, Any] = field(default_factory=dict)
    basis_sha256: str | None = None
    encoder_storage: str = "full"
    basis_prefixes: dict[str, int] = field(default_factory=dict)


#: Values of ``encoder_storage`` this reader knows.
ENCODER_STORAGES = ("full", "compact")
#: Largest ``model.json`` read, bytes (the shipped one is about 64 kB).
MAX_MANIFEST_BYTES = 8 << 20
#: Deepest nesting of objects and lists in ``model.json`` (the shipped one nests 5 deep).
MAX_MANIFEST_DEPTH = 32
#: Longest model name, characters.
MAX_NAME_LENGTH = 256


def _encoder_storage(value: object) -> str:
    if value not in ENCODER_STORAGES:
        raise ValueError(f"encoder_storage {value!r} is not one of {ENCODER_STORAGES}")
    return str(value)


def _refuse_constant(name: str) -> float:
    raise ValueError(f"{name} is not a JSON number")


def _depth(value: object) -> int:
    """Nesting depth of a parsed JSON value (iterative: a deep value cannot exhaust the stack here)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, level = stack.pop()
        if isinstance(item, dict | list):
            deepest = max(deepest, level)
            if deepest > MAX_MANIFEST_DEPTH:
                return deepest
            stack.extend((child, level + 1) for child in (item.values() if isinstance(item, dict) else item))
    return deepest


def _sha256_field(data: dict[str, Any], key: str) -> str:
    value = data[key]
    if not is_sha256_hex(value):
        raise ValueError(f"{key} must be 64 lower-case hex digits, got {repr(value)[:80]}")
    return str(value)


def _object_field(data: dict[str, Any], key: str) -> dict[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise ValueError(f"{key} must be a JSON object, got {type(value).__name__}")
    return value


def parse_manifest(text: bytes, folder: str | os.PathLike[str]) -> ModelManifest:
    """Check ``model.json``'s bytes against the manifest's schema (``spec/model.md`` §3) and read them.

    Raises
    ------
    ValueError
        Not UTF-8 JSON (NaN and infinities are not JSON), nested deeper than :data:`MAX_MANIFEST_DEPTH`,
        not an object, a field missing, of the wrong type or out of bounds (the config:
        :meth:`ModelConfig.from_dict`).
    """
    try:
        data = json.loads(text.decode("utf-8"), parse_constant=_refuse_constant)
    except RecursionError:
        raise ValueError(f"nested deeper than {MAX_MANIFEST_DEPTH} levels") from None
    if _depth(data) > MAX_MANIFEST_DEPTH:
        raise ValueError(f"nested deeper than {MAX_MANIFEST_DEPTH} levels")
    if not isinstance(data, dict):
        raise ValueError(f"a manifest is a JSON object, got {type(data).__name__}")
    missing = [key for key in ("name", "config", "decoder_sha256", "encoder_sha256") if key not in data]
    if missing:
        raise ValueError(f"missing {', '.join(missing)}")
    name = data["name"]
    if not isinstance(name, str) or not 1 <= len(name) <= MAX_NAME_LENGTH:
        raise ValueError(f"name must be a string of 1 to {MAX_NAME_LENGTH} characters, got {repr(name)[:80]}")
    basis = data.get("basis_sha256")
    return ModelManifest(
        name=name,
        config=ModelConfig.from_dict(data["config"]),
        decoder_sha256=_sha256_field(data, "decoder_sha256"),
        encoder_sha256=_sha256_field(data, "encoder_sha256"),
        folder=Path(folder),
        info=_object_field(data, "info"),
        parameters=_object_field(data, "parameters"),
        basis_sha256=None if basis is None else _sha256_field(data, "basis_sha256"),
        encoder_storage=_encoder_storage(data.get("encoder_storage", "full")),
        basis_prefixes=_basis_prefixes(data),
    )


#: Most earlier bases a model's basis may extend.
MAX_BASIS_PREFIXES = 16


def _basis_prefixes(data: dict[str, Any]) -> dict[str, int]:
    """``basis_prefixes`` (absent: none): lower-case SHA-256 → a count in 1 … 4095, only beside a basis."""
    prefixes = data.get("basis_prefixes", {})
    if not isinstance(prefixes, dict) or len(prefixes) > MAX_BASIS_PREFIXES:
        raise ValueError(f"basis_prefixes must be an object of at most {MAX_BASIS_PREFIXES} entries")
    if prefixes and data.get("basis_sha256") is None:
        raise ValueError("basis_prefixes needs a basis_sha256: they name leading parts of that basis")
    out = {}
    for sha, count in prefixes.items():
        if not is_sha256_hex(sha):
            raise ValueError(f"basis_prefixes: {sha[:80]!r} is not a lower-case hex SHA-256")
        if sha == data.get("basis_sha256"):
            raise ValueError("basis_prefixes: the model's own basis is not a prefix of itself")
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count < 4096:
            raise ValueError(f"basis_prefixes: {sha[:12]}…'s count must be a whole number in 1 … 4095")
        out[sha] = count
    return out


def load_manifest(folder: str | os.PathLike[str]) -> ModelManifest:
    """Read ``model.json`` of a model folder (no weights are read), checked against its schema.

    Only a regular file inside the folder of at most :data:`MAX_MANIFEST_BYTES` is read.

    Raises
    ------
    ModelFolderError
        The manifest is missing, not a regular file inside the folder, too large, or not a valid manifest
        (:func:`parse_manifest`); the message names the file.
    """
    path = Path(folder) / MANIFEST
    text = read_folder_file(folder, MANIFEST, limit=MAX_MANIFEST_BYTES, error=ModelFolderError)
    try:
        return parse_manifest(text, folder)
    except (KeyError, TypeError, ValueError) as error:
        raise ModelFolderError(path, f"not a valid model manifest ({error})") from None
