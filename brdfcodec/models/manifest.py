"""Model manifests (``model.json``): what a model folder holds, read without importing torch."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from brdfcodec.errors import BrdfcodecError
from brdfcodec.models.config import ModelConfig

__all__ = ["DECODER_FILE", "ENCODER_FILE", "MANIFEST", "ModelManifest", "load_manifest"]

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


#: Values of ``encoder_storage`` this reader knows.
ENCODER_STORAGES = ("full", "compact")


def _encoder_storage(value: object) -> str:
    if value not in ENCODER_STORAGES:
        raise ValueError(f"encoder_storage {value!r} is not one of {ENCODER_STORAGES}")
    return str(value)


def load_manifest(folder: str | os.PathLike[str]) -> ModelManifest:
    """Read ``model.json`` of a model folder (no weights are read)."""
    path = Path(folder) / MANIFEST
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return ModelManifest(
            name=str(data["name"]),
            config=ModelConfig.from_dict(data["config"]),
            decoder_sha256=str(data["decoder_sha256"]),
            encoder_sha256=str(data["encoder_sha256"]),
            folder=Path(folder),
            info=dict(data.get("info", {})),
            parameters=dict(data.get("parameters", {})),
            basis_sha256=None if data.get("basis_sha256") is None else str(data["basis_sha256"]),
            encoder_storage=_encoder_storage(data.get("encoder_storage", "full")),
        )
    except (KeyError, TypeError, ValueError) as error:
        raise BrdfcodecError(f"{path}: not a valid model manifest ({error})") from None
