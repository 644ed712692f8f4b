"""Turn a finished run into a shippable model folder: weights, manifest with measurements, card."""

from __future__ import annotations

import json
import os
import platform
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from brdfcodec.codec import BrdfDecoder
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.errors import CheckpointError
from brdfcodec.io.atomic import atomic_output
from brdfcodec.models.config import ModelConfig
from brdfcodec.models.network import BetaVAE
from brdfcodec.models.parameters import describe_parameters
from brdfcodec.models.store import DECODER_FILE, MANIFEST, ModelManifest, load_manifest, write_manifest, write_weights
from brdfcodec.training.alignment import align_to_factors
from brdfcodec.training.card import render_model_card
from brdfcodec.training.checkpoint import load_checkpoint
from brdfcodec.training.measurements import kl_per_dim, measure_model, summarise, traversal_changes
from brdfcodec.version import __version__

if TYPE_CHECKING:
    from brdfcodec.layers.shared_basis import SharedBasis

__all__ = ["CARD", "DEFAULT_BASIS_COUNT", "add_shared_basis", "comparison_row", "copy_renamed", "export_run",
           "store_info", "trained_rows", "write_card"]

CARD = "MODEL_CARD.md"
#: Vectors of the shared basis that ``bvae model export`` fits (at most the rank of the fitted data,
#: :func:`~brdfcodec.layers.basis.shared_basis_rank`; float16 vectors over the 387,378 valid entries, stored
#: as factors in a fraction of their dense size).
DEFAULT_BASIS_COUNT = 75

_LIMITS = [
    "Trained and measured on NBRDF proxies (neural fits evaluated on the MERL grid, the card's Data section says "
    "of which families), which are smoother than the measurements; errors on genuine files will be larger.",
    "Materials far from the training set (saturated greens above all; MERL has few) reconstruct worse. "
    "Colour-permutation augmentation is meant to help there; whether it does for this model is in the "
    "comparison table (green-acrylic and the green mean, with and without it).",
    "Float decoding is not bit-exact across devices or PyTorch versions; within one machine and dtype it is.",
]


def export_run(
    run_dir: str | os.PathLike[str],
    folder: str | os.PathLike[str],
    *,
    name: str,
    dataset_path: str | os.PathLike[str] | None = None,
    command: str = "",
    comparisons: dict[str, str | os.PathLike[str]] | None = None,
    basis_count: int = DEFAULT_BASIS_COUNT,
    basis_colour_permutations: bool = True,
    align_materials: int = 0,
    turn_axes: bool = True,
) -> ModelManifest:
    """Export the best weights of a run with every measurement its card needs, and fit its shared basis.

    Parameters
    ----------
    run_dir : str or os.PathLike
        Folder written by :func:`brdfcodec.training.trainer.train`.
    folder : str or os.PathLike
        Output model folder (``encoder.safetensors``, ``decoder.safetensors``,
        ``model.json``, ``MODEL_CARD.md``).
    name : str
        Model name.
    dataset_path : str or os.PathLike, optional
        Dataset to measure on; the run's own by default.
    command : str
        The command that reproduces the run, quoted in the card.
    comparisons : dict of str to path, optional
        Other exported model folders (label → folder) whose measurements the
        card shows beside this model's (a paper-sized model, ablations).
    basis_count : int
        Vectors of the shared basis fitted on the training split (``basis.safetensors``, the basis layer
        of ``spec/bvae-format.md`` §4.4); 0 for none.
    basis_colour_permutations : bool, default True
        Fit that basis on the training materials in all 6 orders of their colour channels (at most
        5N − 1 vectors, :func:`~brdfcodec.layers.basis.shared_basis_rank`), not as measured only: it spans
        materials the model was not trained on better, since a permuted material is a valid one with other
        colours (documentation: Layers and rate control).
    align_materials : int, default 0
        Rotate the latent space, before anything is measured, so that its dimensions follow the analytic
        factors of this many materials (:func:`brdfcodec.training.alignment.align_to_factors`; stored as
        ``info.alignment``); 0 keeps the trained axes.
    turn_axes : bool, default True
        With ``align_materials``: turn the axes (the default), or only measure how the trained axes follow the
        factors (``info.alignment`` with the identity rotation; a run fine-tuned from an aligned model).
    """
    run = Path(run_dir)
    run_info = json.loads((run / "run.json").read_text())
    best_file = run / "best.pt"
    best = load_checkpoint(best_file, required={"model": dict, "epoch": int, "model_config": str})
    try:
        config = ModelConfig.from_dict(json.loads(best["model_config"]))
        model = BetaVAE(config)
        model.load_state_dict(best["model"])
    except (RecursionError, RuntimeError, ValueError) as error:
        raise CheckpointError(best_file, f"its weights do not fit its model config "
                              f"({str(error).strip().splitlines()[0][:200]})") from None
    model.eval()
    alignment = (align_to_factors(model, materials=align_materials, rotate=turn_axes) if align_materials
                 else None)
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    summary_file = run / "summary.json"
    seconds = sum(record["seconds"] for record in log)
    with BrdfDataset(dataset_path or run_info["dataset"]) as dataset:
        train_rows = trained_rows(dataset, run_info)
        measured = measure_model(model.encoder, model.decoder, dataset, config.latent_dim, train_rows)
        errors, baseline = measured.errors, measured.pca_errors
        mu, logvar = measured.mu[train_rows], measured.logvar[train_rows]
        kl = kl_per_dim(mu, logvar)
        traversal = traversal_changes(model.decoder, mu.mean(0), np.maximum(mu.std(0), 1e-6))
        trained = set(train_rows)
        data = {"source_kind": dataset.source_kind, "description": dataset.description,
                "train": [dataset.names[i] for i in train_rows],
                "validation": [name for i, name in enumerate(dataset.names) if i not in trained]}
        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        basis = (_fit_basis(out, dataset, train_rows, basis_count, basis_colour_permutations) if basis_count
                 else None)
    info: dict[str, Any] = {
        "brdfcodec_version": __version__,
        "torch_version": torch.__version__,
        "data": data,
        "train_config": run_info["train_config"],
        "world_size": run_info["world_size"],
        "device": f"{platform.processor() or platform.machine()} CPU" if not torch.cuda.is_available()
        else torch.cuda.get_device_name(0),
        "epochs_done": log[-1]["epoch"],
        "best_epoch": best["epoch"],
        "training_seconds": seconds,
        "stop_reason": json.loads(summary_file.read_text())["stop_reason"] if summary_file.exists() else "",
        "command": command,
        "errors": [row.as_dict() for row in errors],
        "summary": summarise(errors),
        "pca_errors": [row.as_dict() for row in baseline],
        "pca_summary": summarise(baseline),
        "kl_per_dim": kl,
        "latent_mean": mu.mean(0).tolist(),
        "latent_std": mu.std(0).tolist(),
        "traversal": traversal,
        "limits": _LIMITS,
    }
    if alignment is not None:
        info["alignment"] = alignment.as_dict()
    if "initial_model" in run_info:
        info["initial_model"] = run_info["initial_model"]
    info["comparisons"] = [comparison_row("this model", info, None)]
    for label, other in (comparisons or {}).items():
        other_manifest = json.loads((Path(other) / MANIFEST).read_text())
        info["comparisons"].append(comparison_row(label, other_manifest["info"], Path(other)))
    identity = write_weights(model, out, name=name, compact=config.linear_basis)
    info["decoder_bytes"] = identity["decoder_bytes"]
    info["encoder_bytes"] = identity["encoder_bytes"]
    info["comparisons"][0]["decoder_bytes"] = info["decoder_bytes"]
    manifest = {key: identity[key] for key in ("name", "config", "decoder_sha256", "encoder_sha256",
                                               "encoder_storage")}
    if basis is not None:
        manifest["basis_sha256"] = basis.pop("sha256")
        info["basis"] = basis
    manifest["info"] = info
    manifest["parameters"] = describe_parameters(
        BrdfDecoder.from_network(model.decoder),
        factors=() if alignment is None else list(zip(alignment.factor_names, alignment.correlation, strict=True)))
    write_card(out, manifest)
    return write_manifest(out, manifest)  # last: a folder with a model.json is a complete model


def trained_rows(dataset: BrdfDataset, run_info: dict[str, Any]) -> list[int]:
    """Rows of the materials the run trained on (``run.json``: its folds or families, not only the stored
    split), or the dataset's training split when the run's materials are not all in this dataset."""
    data = run_info.get("data")  # free-form: a model made by hand may describe its data in words
    listed = data.get("train", []) if isinstance(data, dict) else []
    trained = {name for name in listed if isinstance(name, str)} if isinstance(listed, list) else set()
    rows = [i for i, name in enumerate(dataset.names) if name in trained]
    return rows if trained and len(rows) == len(trained) else dataset.indices("train")


def _fit_basis(folder: Path, dataset: BrdfDataset, rows: list[int], count: int, colour_permutations: bool,
               name: str | None = None, extends: SharedBasis | None = None) -> dict[str, Any]:
    """Fit the shared basis on the given (training) materials, then write it into ``folder`` as ``name``
    (``basis.safetensors`` by default; atomically: a failed fit leaves any basis there as it was).
    With ``extends``, the basis written is that one followed by the fit's later vectors
    (:func:`~brdfcodec.layers.basis.extend_factorised_basis`).

    With ``colour_permutations`` the file holds the basis' factors (``spec/model.md`` §5), a third of the
    dense vectors' size."""
    from brdfcodec.layers.basis import (
        BASIS_FILE,
        extend_factorised_basis,
        fit_factorised_basis,
        fit_shared_basis,
        shared_basis_rank,
        write_factorised_basis,
        write_shared_basis,
    )

    if len(rows) < 2:
        raise ValueError(f"{dataset.path}: a shared basis needs at least 2 training materials")
    count = min(count, shared_basis_rank(len(rows), colour_permutations))  # no more vectors than the data's rank
    path = folder / (name or BASIS_FILE)
    if extends is not None and (extends.factorised is None or not colour_permutations):
        raise ValueError("only a basis fitted in all 6 colour orders (stored as factors) can be extended")
    if extends is not None and count <= extends.count:
        raise ValueError(f"the basis holds {extends.count} vectors; extending it needs a count above that "
                         f"(at most {shared_basis_rank(len(rows), colour_permutations)} for these materials)")
    if colour_permutations:
        factorised = fit_factorised_basis(dataset.inputs(rows), dataset.input_masks(rows), count)
        if extends is not None:
            assert extends.factorised is not None
            factorised = extend_factorised_basis(extends.factorised, factorised)
        sha = write_factorised_basis(path, factorised)
        n_entries = 3 * len(factorised.colour_entries)
    else:
        components, entries = fit_shared_basis(dataset.inputs(rows), dataset.input_masks(rows), count)
        sha = write_shared_basis(path, components, entries)
        n_entries = len(entries)
    kind = "principal components of the training split's mapped kept slices (valid entries)"
    if colour_permutations:
        kind += " in all 6 orders of their colour channels, stored as factors"
    return {"sha256": sha, "count": int(count), "entries": n_entries, "fitted_on": "train",
            "materials": len(rows), "colour_permutations": colour_permutations,
            "bytes": path.stat().st_size, "kind": kind}


def add_shared_basis(folder: str | os.PathLike[str], dataset_path: str | os.PathLike[str],
                     count: int = DEFAULT_BASIS_COUNT, *, colour_permutations: bool = True,
                     replace: bool = False, extend: bool = False) -> ModelManifest:
    """Fit a shared basis for an exported model and name it in ``model.json``.

    The basis is fitted on the materials the model trained on (``info.data.train`` of its ``model.json``:
    a cross-validation fold's or a family's, as :func:`export_run` fits it), or on the dataset's training
    split when the model does not list them or the dataset lacks one of them.

    For a model exported before shared bases existed (:func:`export_run` fits one itself), or, with
    ``replace``, to give a model a new basis: the new one replaces the old one (a model ships one basis), so
    files whose basis layers name the old one no longer decode with this folder (the decoder refuses them,
    naming both hashes). The weights are not touched, so the model's identity (its decoder hash) is unchanged.
    ``colour_permutations`` as in :func:`export_run`. With ``extend``, the model's basis grows to ``count``
    vectors instead: its vectors are kept bit for bit and the fit's later ones follow, and ``model.json`` names
    the old basis (and any it extended) in ``basis_prefixes``, so every file made with the model keeps decoding
    (``spec/model.md`` §5). The basis file is written only once the fit has succeeded: a failed fit leaves the
    model as it was.

    Raises
    ------
    FileExistsError
        The model already has a shared basis and neither ``replace`` nor ``extend`` is given.
    ValueError
        ``extend`` without a basis fitted in the 6 colour orders to extend, or a count not above its size.
    """
    from brdfcodec.layers.basis import BASIS_FILE, load_shared_basis

    out = Path(folder)
    manifest = json.loads((out / MANIFEST).read_text())
    existing = manifest.get("basis_sha256")
    if replace and extend:
        raise ValueError("--replace and --extend exclude each other: extend keeps the basis, replace drops it")
    if existing and not (replace or extend):
        raise FileExistsError(
            f"{folder}: the model already has a shared basis ({existing[:12]}…). --extend adds vectors to it "
            "(files made with it keep decoding); --replace fits a new one that replaces it (files with basis "
            "layers made with it then no longer decode with this folder)"
        )
    if extend and not existing:
        raise ValueError(f"{folder}: the model has no shared basis to extend")
    extends = load_shared_basis(out / BASIS_FILE, existing) if extend else None
    fitting = ".basis-fitting.safetensors"
    trained_on = manifest.get("info", {})  # its "data" names the materials
    with BrdfDataset(dataset_path) as dataset:
        basis = _fit_basis(out, dataset, trained_rows(dataset, trained_on), count, colour_permutations,
                           name=fitting, extends=extends)
    os.replace(out / fitting, out / BASIS_FILE)
    prefixes = {**manifest.get("basis_prefixes", {}), existing: extends.count} if extends is not None else {}

    def add(stored: dict[str, Any]) -> None:
        stored["basis_sha256"] = basis.pop("sha256")
        stored.setdefault("info", {})["basis"] = basis
        stored.pop("previous_bases", None)  # a manifest of format 1.x of spec/model.md may list some
        if prefixes:
            stored["basis_prefixes"] = prefixes
            basis["extends"] = {sha: {"count": n} for sha, n in prefixes.items()}
        else:
            stored.pop("basis_prefixes", None)

    return _rewrite_manifest(folder, add)


def store_info(folder: str | os.PathLike[str], key: str, value: Any) -> ModelManifest:
    """Add a measurement to ``info`` in ``model.json`` and rewrite the card (weights and identity untouched)."""

    def add(stored: dict[str, Any]) -> None:
        stored.setdefault("info", {})[key] = value

    return _rewrite_manifest(folder, add)


def _rewrite_manifest(folder: str | os.PathLike[str], change: Callable[[dict[str, Any]], None]) -> ModelManifest:
    """Read ``model.json``, apply ``change`` to it, then write the card and ``model.json`` (atomically, in order)."""
    out = Path(folder)
    stored = json.loads((out / MANIFEST).read_text())
    change(stored)
    if _has_card(out, stored):
        write_card(out, stored)
    return write_manifest(out, stored)


def _has_card(folder: Path, manifest: dict[str, Any]) -> bool:
    """Whether the model's card can be written again: it has one, or its ``info`` holds an exported run's
    measurements. A model made otherwise (by hand, or :func:`~brdfcodec.models.store.export_model` alone) has
    no card to rewrite, and its ``model.json`` changes without one."""
    return (folder / CARD).is_file() or isinstance(manifest.get("info", {}).get("train_config"), dict)


def copy_renamed(source: str | os.PathLike[str], destination: str | os.PathLike[str], name: str) -> ModelManifest:
    """Copy an exported model under a new name: the same tensors, new weight files (their metadata names the
    model, so the decoder hash changes), the same measurements and basis, a card with the new name.

    For a release made from a run exported under a working name. ``destination`` must not exist; it is
    written in a temporary folder beside it and renamed when complete.
    """
    import shutil

    from brdfcodec.layers.basis import BASIS_FILE
    from brdfcodec.models.store import load_model

    out = Path(destination)
    if out.exists():
        raise FileExistsError(f"{out}: already exists")
    encoder, decoder, manifest = load_model(source)
    assert encoder is not None and decoder is not None
    model = BetaVAE(manifest.config)
    model.encoder.load_state_dict(encoder.state_dict())
    model.decoder.load_state_dict(decoder.state_dict())
    building = out.with_name(f".{out.name}.building")
    shutil.rmtree(building, ignore_errors=True)
    identity = write_weights(model, building, name=name, compact=manifest.encoder_storage == "compact")
    if (Path(source) / BASIS_FILE).exists():
        shutil.copy2(Path(source) / BASIS_FILE, building / BASIS_FILE)
    stored = json.loads((Path(source) / MANIFEST).read_text(encoding="utf-8"))
    stored.update({key: identity[key] for key in ("name", "decoder_sha256", "encoder_sha256", "encoder_storage")})
    info = stored.setdefault("info", {})
    info["decoder_bytes"], info["encoder_bytes"] = identity["decoder_bytes"], identity["encoder_bytes"]
    if info.get("comparisons"):
        info["comparisons"][0]["decoder_bytes"] = identity["decoder_bytes"]
    write_card(building, stored)
    write_manifest(building, stored)
    os.replace(building, out)
    return load_manifest(out)


def write_card(folder: str | os.PathLike[str], manifest: dict[str, Any]) -> Path:
    """Write ``MODEL_CARD.md`` from a manifest, atomically."""
    path = Path(folder) / CARD
    with atomic_output(path, overwrite=True) as tmp:
        tmp.write_text(render_model_card(manifest), encoding="utf-8")
    return path


def add_named_parameters(folder: str | Path) -> dict[str, Any]:
    """Measure what each latent dimension controls, store it as ``parameters`` in ``model.json``, rewrite the card.

    For a model exported before named parameters existed, or before aligned dimensions were named by their
    factor (``info.alignment``; :func:`export_run` measures them itself). The
    weights are not touched, so the model's identity (its decoder hash) is unchanged.
    """
    manifest = load_manifest(folder)
    alignment = manifest.info.get("alignment")
    factors = list(zip(alignment["factor_names"], alignment["correlation"], strict=False)) if alignment else []
    parameters = describe_parameters(BrdfDecoder(manifest), factors=factors)

    def add(stored: dict[str, Any]) -> None:
        stored["parameters"] = parameters

    _rewrite_manifest(folder, add)
    return parameters


#: Materials of the proxy whose colour is green (the paper's hard case).
GREEN_MATERIALS = ("green-acrylic", "green-fabric", "green-latex", "green-metallic-paint", "green-metallic-paint2",
                   "green-plastic", "specular-green-phenolic")


def comparison_row(label: str, info: dict[str, Any], folder: Path | None) -> dict[str, Any]:
    """A model's row of the card's comparison table, from its manifest's ``info`` (``folder``: where its decoder
    file is, for its size; None when not written yet)."""
    errors = {row["name"]: row for row in info["errors"]}
    greens = [errors[n]["relae_mapped"] for n in GREEN_MATERIALS if n in errors]
    return {
        "label": label,
        "decoder_bytes": (folder / DECODER_FILE).stat().st_size if folder else None,
        "epochs": info["epochs_done"],
        "minutes": info["training_seconds"] / 60,
        "train_mapped_mean": info["summary"]["train"]["mapped_mean"],
        "validation_mapped_mean": info["summary"].get("validation", {}).get("mapped_mean"),
        "validation_mapped_max": info["summary"].get("validation", {}).get("mapped_max"),
        "worst_mapped": max(row["relae_mapped"] for row in info["errors"]),
        "green_acrylic": errors.get("green-acrylic", {}).get("relae_mapped"),
        "green_mean": sum(greens) / len(greens) if greens else None,
        "permute_colours": info["train_config"]["permute_colours"],
    }
