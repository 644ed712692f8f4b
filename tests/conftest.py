"""Shared fixtures: analytic MERL files made on the fly, and the project's shared data when present."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.io.merl import MerlBRDF, write_merl

REPO_ROOT = Path(__file__).resolve().parents[1]
#: The earlier default models, no longer in the wheel (issue 52): the package brdfcodec-legacy-models in this
#: source tree. Registered for the whole test run, so that the tests that decode their files (the spec's
#: vectors among them) run whether or not that package is installed.
LEGACY_MODELS = REPO_ROOT / "packages" / "brdfcodec-legacy-models" / "brdfcodec_legacy_models" / "models"
#: The opt-in editing model (issue 50), a package of its own too: registered the same way, so that
#: ``--model editing`` and its files work in every test run.
EDITING_MODELS = REPO_ROOT / "packages" / "brdfcodec-editing-model" / "brdfcodec_editing_model" / "models"


def _register_legacy_models() -> None:
    from brdfcodec.models.registry import register_model_folder

    for folder in sorted([*LEGACY_MODELS.glob("*/model.json"), *EDITING_MODELS.glob("*/model.json")]):
        register_model_folder(folder.parent)


_register_legacy_models()


def shared_root() -> Path:
    """``$BRDFCODEC_SHARED``, else the ``shared`` folder beside the checkout."""
    return Path(os.environ.get("BRDFCODEC_SHARED", REPO_ROOT.parent / "shared"))


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    root = shared_root()
    if not (root / "data").is_dir():
        pytest.skip(f"shared data not found at {root} (set BRDFCODEC_SHARED to the folder holding data/)")
    return root


@pytest.fixture(scope="session")
def nbrdf_zip(shared_dir: Path) -> Path:
    archive = shared_dir / "data" / "merl-nbrdf-90.zip"
    if not archive.is_file():
        pytest.skip(f"NBRDF proxy archive not found at {archive}")
    return archive


@pytest.fixture(scope="session")
def analytic_tables() -> dict[str, MerlBRDF]:
    """Every analytic preset as a MERL table (computed once per session)."""
    return {name: preset.to_merl() for name, preset in ANALYTIC_PRESETS.items()}


@pytest.fixture(scope="session")
def red_plastic_file(tmp_path_factory: pytest.TempPathFactory, analytic_tables: dict[str, MerlBRDF]) -> Path:
    path = tmp_path_factory.mktemp("merl") / "red-plastic.binary"
    write_merl(path, analytic_tables["red-plastic"])
    return path


@pytest.fixture(scope="session")
def analytic_training_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dataset of 12 random analytic materials (a fifth held out) for short training runs."""
    from brdfcodec.datasets.hdf5 import build_dataset
    from brdfcodec.datasets.sources import analytic_sources

    path = tmp_path_factory.mktemp("analytic-training") / "analytic.h5"
    build_dataset(path, analytic_sources(random_count=12), source_kind="analytic", description="analytic test set",
                  validation_fraction=0.2, seed=0, progress=False)
    return path


@pytest.fixture(scope="session")
def tiny_model_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A randomly initialised tiny model (with a linear basis path), exported like a trained one."""
    import dataclasses

    import torch

    from brdfcodec.models.config import TINY_CONFIG
    from brdfcodec.models.network import BetaVAE
    from brdfcodec.models.store import export_model

    torch.manual_seed(7)
    model = BetaVAE(dataclasses.replace(TINY_CONFIG, linear_basis=True)).eval()
    with torch.no_grad():  # a non-trivial basis so that codes change the output
        model.decoder.basis_mean.uniform_(0.2, 1.5)
        model.decoder.basis_components.normal_(0.0, 0.05)
        model.decoder.upsample[-1].bias.normal_(0.0, 0.1)
    folder = tmp_path_factory.mktemp("models") / "tiny"
    export_model(model, folder, name="tiny-test-model", info={"data": "none (random initialisation)"})
    return folder
