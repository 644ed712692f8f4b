"""Trained models on disk: safetensors weights, a manifest, and SHA-256 checks.

A model folder holds::

    encoder.safetensors   encoder weights
    decoder.safetensors   decoder weights
    model.json            manifest: name, ModelConfig, SHA-256 of both weight files, training facts

A decoder is identified by the SHA-256 of ``decoder.safetensors`` (the bytes
of the file): ``.bvae`` files refer to their decoder by it. Loading verifies
the hash before any weight is read, so a corrupted or swapped file is never
used.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from brdfcodec.errors import BrdfcodecError
from brdfcodec.genuine import sha256_of_file
from brdfcodec.models.manifest import DECODER_FILE, ENCODER_FILE, MANIFEST, ModelManifest, load_manifest
from brdfcodec.models.network import BetaVAE, Decoder, Encoder

__all__ = ["MANIFEST", "ModelChecksumError", "ModelManifest", "export_model", "load_manifest", "load_model"]

class ModelChecksumError(BrdfcodecError):
    """A weight file's SHA-256 differs from its manifest: the file is corrupt or not the named model."""


def export_model(model: BetaVAE, folder: str | os.PathLike[str], *, name: str, info: dict[str, Any]) -> ModelManifest:
    """Write a trained model as safetensors plus manifest.

    Parameters
    ----------
    model : BetaVAE
        Trained network (moved to CPU float32 for export).
    folder : str or os.PathLike
        Created if absent; existing files of the same names are replaced.
    name : str
        Readable name stored in the manifest and the files' metadata.
    info : dict
        JSON-serialisable training facts.
    """
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    metadata = {"brdfcodec_model": name, "config": model.config.to_json()}
    for part, module, file in (("encoder", model.encoder, ENCODER_FILE), ("decoder", model.decoder, DECODER_FILE)):
        # Floating tensors keep their dtype (the linear basis is float16 by design); integers stay as they are.
        tensors = {k: v.detach().to("cpu").contiguous() for k, v in module.state_dict().items()}
        save_file(tensors, str(out / file), metadata={**metadata, "part": part})
        os.chmod(out / file, 0o644)
    manifest = {
        "name": name,
        "config": json.loads(model.config.to_json()),
        "decoder_sha256": sha256_of_file(out / DECODER_FILE),
        "encoder_sha256": sha256_of_file(out / ENCODER_FILE),
        "info": info,
    }
    (out / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return load_manifest(out)


def _verified_weights(manifest: ModelManifest, file: str, expected: str) -> dict[str, torch.Tensor]:
    path = manifest.folder / file
    actual = sha256_of_file(path)
    if actual != expected:
        raise ModelChecksumError(
            f"{path}: SHA-256 {actual} differs from the manifest's {expected}; the file is corrupt or belongs "
            "to another model (reinstall brdfcodec, or re-export the model)"
        )
    return load_file(str(path))


def load_model(
    folder: str | os.PathLike[str], *, parts: tuple[str, ...] = ("encoder", "decoder"), device: str = "cpu"
) -> tuple[Encoder | None, Decoder | None, ModelManifest]:
    """Load a model's encoder and/or decoder after verifying their SHA-256.

    Returns
    -------
    encoder, decoder : Encoder or None, Decoder or None
        In evaluation mode; None for a part not asked for.
    manifest : ModelManifest
    """
    manifest = load_manifest(folder)
    encoder = decoder = None
    if "encoder" in parts:
        encoder = Encoder(manifest.config)
        encoder.load_state_dict(_verified_weights(manifest, ENCODER_FILE, manifest.encoder_sha256))
        encoder = encoder.to(device).eval()
    if "decoder" in parts:
        decoder = Decoder(manifest.config)
        decoder.load_state_dict(_verified_weights(manifest, DECODER_FILE, manifest.decoder_sha256))
        decoder = decoder.to(device).eval()
    return encoder, decoder, manifest
