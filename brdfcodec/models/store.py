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

import hashlib
import json
import os
from dataclasses import fields
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load, save_file

from brdfcodec.errors import ModelChecksumError, ModelFolderError
from brdfcodec.io.atomic import atomic_folder, atomic_output
from brdfcodec.io.folder_files import read_folder_file
from brdfcodec.io.hashing import sha256_of_file
from brdfcodec.models.config import ModelConfig
from brdfcodec.models.manifest import DECODER_FILE, ENCODER_FILE, MANIFEST, ModelManifest, load_manifest
from brdfcodec.models.network import BetaVAE, Decoder, Encoder

__all__ = [
    "MANIFEST",
    "MAX_WEIGHT_BYTES",
    "ModelChecksumError",
    "ModelFolderError",
    "ModelManifest",
    "compact_encoder",
    "compact_encoder_tensors",
    "expand_encoder_tensors",
    "export_model",
    "load_manifest",
    "load_model",
    "write_manifest",
    "write_weights",
]


def write_weights(
    model: BetaVAE, folder: str | os.PathLike[str], *, name: str, compact: bool = False
) -> dict[str, Any]:
    """Write the encoder's and decoder's weights as safetensors (atomically, each file), nothing else.

    Parameters
    ----------
    model : BetaVAE
        Trained network (tensors copied to CPU; floating tensors keep their dtype).
    folder : str or os.PathLike
        Created if absent; existing weight files are replaced.
    name : str
        Readable name stored in the files' metadata.
    compact : bool
        Store the encoder compactly (:func:`compact_encoder_tensors`; only for a model with a linear basis).

    Returns
    -------
    dict
        The manifest's identity fields: ``name``, ``config``, ``decoder_sha256``,
        ``encoder_sha256``, ``encoder_storage``, and the two files' sizes in bytes (``decoder_bytes``,
        ``encoder_bytes``).
    """
    if compact and not model.config.linear_basis:
        raise ValueError("compact encoder storage needs a model with a linear basis (it is derived from the decoder's)")
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    metadata = {"brdfcodec_model": name, "config": model.config.to_json()}
    for part, module, file in (("encoder", model.encoder, ENCODER_FILE), ("decoder", model.decoder, DECODER_FILE)):
        # Floating tensors keep their dtype (the linear basis is float16 by design); integers stay as they are.
        tensors = {k: v.detach().to("cpu").contiguous() for k, v in module.state_dict().items()}
        extra = {}
        if compact and part == "encoder":
            tensors, extra = compact_encoder_tensors(tensors), {"storage": "compact"}
        with atomic_output(out / file, overwrite=True) as tmp:
            save_file(tensors, str(tmp), metadata={**metadata, "part": part, **extra})
        os.chmod(out / file, 0o644)
    return {
        "encoder_storage": "compact" if compact else "full",
        "name": name,
        "config": json.loads(model.config.to_json()),
        "decoder_sha256": sha256_of_file(out / DECODER_FILE),
        "encoder_sha256": sha256_of_file(out / ENCODER_FILE),
        "decoder_bytes": (out / DECODER_FILE).stat().st_size,
        "encoder_bytes": (out / ENCODER_FILE).stat().st_size,
    }


def write_manifest(folder: str | os.PathLike[str], manifest: dict[str, Any]) -> ModelManifest:
    """Write ``model.json`` once, atomically (sorted keys, 2-space indent), and load it back."""
    out = Path(folder)
    with atomic_output(out / MANIFEST, overwrite=True) as tmp:
        tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return load_manifest(out)


def export_model(
    model: BetaVAE,
    folder: str | os.PathLike[str],
    *,
    name: str,
    info: dict[str, Any],
    parameters: dict[str, Any] | None = None,
) -> ModelManifest:
    """Write a trained model as safetensors plus manifest (``model.json`` written once, atomically).

    Parameters
    ----------
    model : BetaVAE
        Trained network.
    folder : str or os.PathLike
        Created if absent; existing files of the same names are replaced.
    name : str
        Readable name stored in the manifest and the files' metadata.
    info : dict
        JSON-serialisable training facts.
    parameters : dict, optional
        The named parameters (:func:`brdfcodec.models.parameters.describe_parameters`).
    """
    identity = write_weights(model, folder, name=name)
    manifest = {key: identity[key] for key in ("name", "config", "decoder_sha256", "encoder_sha256")}
    manifest["info"] = info
    if parameters is not None:
        manifest["parameters"] = parameters
    return write_manifest(folder, manifest)


#: Largest weight file read, bytes (the shipped decoder is 9.7 MB; the paper's whole model 79 MB).
MAX_WEIGHT_BYTES = 512 << 20


def _safetensors_metadata(data: bytes, path: Path) -> dict[str, str]:
    """The ``__metadata__`` map of a safetensors file's bytes (header bounds checked)."""
    if len(data) < 8:
        raise ModelFolderError(path, "too short for a safetensors file")
    size = int.from_bytes(data[:8], "little")
    if size > len(data) - 8:
        raise ModelFolderError(path, f"safetensors header of {size:,} bytes runs past the file's end")
    try:
        header = json.loads(data[8 : 8 + size].decode("utf-8"))
    except (RecursionError, ValueError) as error:
        raise ModelFolderError(path, f"safetensors header is not JSON ({error})") from None
    metadata = header.get("__metadata__", {}) if isinstance(header, dict) else None
    if not isinstance(metadata, dict):
        raise ModelFolderError(path, "safetensors header is not an object with a metadata map")
    return metadata


def _stored_config(metadata: dict[str, str], path: Path) -> ModelConfig:
    """The config a weight file's metadata holds (``spec/model.md`` §3): it is covered by the file's hash."""
    text = metadata.get("config")
    if not isinstance(text, str):
        raise ModelFolderError(path, "the weights' metadata holds no model config (spec/model.md §3)")
    try:
        return ModelConfig.from_dict(json.loads(text))
    except (RecursionError, ValueError) as error:
        raise ModelFolderError(path, f"the weights' metadata holds an invalid model config ({error})") from None


def _config_difference(manifest: ModelConfig, stored: ModelConfig) -> str:
    return ", ".join(f"{f.name} {getattr(manifest, f.name)!r} in model.json, {getattr(stored, f.name)!r} in the "
                     "weights" for f in fields(ModelConfig) if getattr(manifest, f.name) != getattr(stored, f.name))


def _verified_weights(manifest: ModelManifest, file: str, expected: str) -> dict[str, torch.Tensor]:
    """A weight file's tensors, once its bytes match ``expected``, its stored config the manifest's, and every
    floating value is finite; only a regular file inside the folder of at most :data:`MAX_WEIGHT_BYTES` is read."""
    path = manifest.folder / file
    data = read_folder_file(manifest.folder, file, limit=MAX_WEIGHT_BYTES, error=ModelFolderError)
    actual = hashlib.sha256(data).hexdigest()
    if actual != expected:
        raise ModelChecksumError(
            f"{path}: SHA-256 {actual} differs from the manifest's {expected}; the file is corrupt or belongs "
            "to another model (reinstall brdfcodec, or re-export the model)"
        )
    stored = _stored_config(_safetensors_metadata(data, path), path)
    if stored != manifest.config:
        raise ModelFolderError(
            path, f"model.json's config differs from the one stored in the weights ({_config_difference(manifest.config, stored)}); "
            "the weights' own config, covered by their SHA-256, is the model's: re-export the model or restore its model.json"
        )
    try:
        tensors = load(data)
    except SafetensorError as error:
        raise ModelFolderError(path, f"not a readable safetensors file ({error})") from None
    for key, value in tensors.items():
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise ModelFolderError(path, f"tensor {key!r} holds non-finite values")
    return tensors


def _matching_state(module: type[torch.nn.Module], config: ModelConfig, tensors: dict[str, torch.Tensor],
                    path: Path) -> None:
    """Refuse tensors whose names or shapes are not those of ``module(config)``: compared with the network
    built on the meta device (no memory), so nothing is allocated for a network the weights do not fit."""
    with torch.device("meta"):
        expected = {key: tuple(value.shape) for key, value in module(config).state_dict().items()}
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    if missing or unexpected:
        raise ModelFolderError(path, f"the tensors are not those of the config's network (missing {missing[:5]}, "
                               f"unexpected {unexpected[:5]})")
    for key, shape in expected.items():
        if tuple(tensors[key].shape) != shape:
            raise ModelFolderError(path, f"tensor {key!r} has shape {tuple(tensors[key].shape)}, the config's "
                                   f"network needs {shape}")


#: Floating tensors of at least this many elements are stored as float16 in a compact encoder file.
_COMPACT_MIN_ELEMENTS = 1 << 16
#: Encoder buffers a compact file leaves out: they are derived from the decoder's linear basis.
_DERIVED_FROM_DECODER = ("basis_mean", "basis_projection")


def compact_encoder_tensors(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """An encoder's tensors as a compact file stores them (``spec/model.md`` §3).

    The linear path's buffers are left out (the encoder's projection is the least-squares inverse of the
    decoder's components, ``(C Cᵀ)⁻¹ C``, and both share the mean), and floating tensors of 65,536 elements or more (the
    fully connected layer) are stored as float16.
    """
    out = {}
    for key, value in state.items():
        if key in _DERIVED_FROM_DECODER:
            continue
        value = value.detach().to("cpu").contiguous()
        if value.is_floating_point() and value.numel() >= _COMPACT_MIN_ELEMENTS:
            value = value.half()
        out[key] = value
    return out


def expand_encoder_tensors(
    tensors: dict[str, torch.Tensor], decoder_tensors: dict[str, torch.Tensor]
) -> dict[str, torch.Tensor]:
    """Inverse of :func:`compact_encoder_tensors`: float32 tensors, the linear path rebuilt from the decoder's."""
    out = {key: value.float() if value.is_floating_point() else value for key, value in tensors.items()}
    if "basis_components" in decoder_tensors:
        components = decoder_tensors["basis_components"].double()
        out["basis_mean"] = decoder_tensors["basis_mean"].float()
        # The least-squares inverse of the decoder's linear path, (C Cᵀ)⁻¹ C: each row divided by its squared
        # norm when the rows are orthogonal (principal components), and right for rotated ones too.
        out["basis_projection"] = torch.linalg.solve(components @ components.T, components).float()
    return out


def compact_encoder(folder: str | os.PathLike[str]) -> ModelManifest:
    """Rewrite a model folder's encoder in compact storage and update ``model.json`` (the decoder is untouched).

    The encoder's outputs change by the float16 rounding of its large matrices; the decoder hash, and every
    file made with the model, stay valid.
    """
    manifest = load_manifest(folder)
    if manifest.encoder_storage == "compact":
        return manifest
    encoder, _, _ = load_model(folder, parts=("encoder",))
    assert encoder is not None
    metadata = {"brdfcodec_model": manifest.name, "config": manifest.config.to_json(), "part": "encoder",
                "storage": "compact"}
    # The folder replaced as a whole: never an encoder file whose hash model.json does not name yet.
    with atomic_folder(folder, replace=True) as out:
        with atomic_output(out / ENCODER_FILE, overwrite=True) as tmp:
            save_file(compact_encoder_tensors(encoder.state_dict()), str(tmp), metadata=metadata)
        os.chmod(out / ENCODER_FILE, 0o644)
        stored = json.loads((out / MANIFEST).read_text(encoding="utf-8"))
        stored["encoder_sha256"] = sha256_of_file(out / ENCODER_FILE)
        stored["encoder_storage"] = "compact"
        stored.setdefault("info", {})["encoder_bytes"] = (out / ENCODER_FILE).stat().st_size
        write_manifest(out, stored)
    return load_manifest(folder)


def load_model(
    folder: str | os.PathLike[str], *, parts: tuple[str, ...] = ("encoder", "decoder"), device: str = "cpu"
) -> tuple[Encoder | None, Decoder | None, ModelManifest]:
    """Load a model's encoder and/or decoder after verifying them (``spec/model.md`` §3).

    In order, before any network is built: ``model.json`` is checked against its schema and bounds, each weight
    file's SHA-256 against the manifest, the config stored in the weights (covered by that hash) against
    ``model.json``'s, every floating value for finiteness, and the tensors' names and shapes against the
    config's network. Only regular files inside the folder, of bounded size, are read.

    Returns
    -------
    encoder, decoder : Encoder or None, Decoder or None
        In evaluation mode; None for a part not asked for.
    manifest : ModelManifest

    Raises
    ------
    ModelFolderError
        The folder, a file in it, or the weights fail a check above; the message names the file.
    ModelChecksumError
        A weight file's SHA-256 differs from the manifest's.
    """
    manifest = load_manifest(folder)
    decoder_path, encoder_path = manifest.folder / DECODER_FILE, manifest.folder / ENCODER_FILE
    decoder_tensors = None
    if "decoder" in parts or ("encoder" in parts and manifest.encoder_storage == "compact"):
        decoder_tensors = _verified_weights(manifest, DECODER_FILE, manifest.decoder_sha256)
        _matching_state(Decoder, manifest.config, decoder_tensors, decoder_path)
    encoder = decoder = None
    if "encoder" in parts:
        tensors = _verified_weights(manifest, ENCODER_FILE, manifest.encoder_sha256)
        if manifest.encoder_storage == "compact":
            assert decoder_tensors is not None
            try:
                tensors = expand_encoder_tensors(tensors, decoder_tensors)
            except (RuntimeError, ValueError) as error:  # torch.linalg.LinAlgError: a singular basis
                raise ModelFolderError(encoder_path, f"the compact encoder cannot be rebuilt from the decoder's "
                                       f"basis ({str(error).splitlines()[0]})") from None
        _matching_state(Encoder, manifest.config, tensors, encoder_path)
        encoder = Encoder(manifest.config)
        encoder.load_state_dict(tensors)
        encoder = encoder.to(device).eval()
    if "decoder" in parts:
        assert decoder_tensors is not None
        decoder = Decoder(manifest.config)
        decoder.load_state_dict(decoder_tensors)
        decoder = decoder.to(device).eval()
    return encoder, decoder, manifest
