"""One model in the wheel; the earlier defaults in brdfcodec-legacy-models (issue 52, item 1).

The wheel ships the default model only. The models it retired live in ``packages/brdfcodec-legacy-models``,
found through the entry point group ``brdfcodec.models`` once installed (the tests' conftest registers the
source tree's folders, so that their files decode in every test run). A file that names a retired decoder,
opened without them, is refused with a typed error that says what to install or set.
"""

from __future__ import annotations

import importlib.metadata
import json
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.cli.main import main
from brdfcodec.errors import ModelNotFoundError
from brdfcodec.format.bvae import DecoderReference, LatentRecord, write_bvae
from brdfcodec.models import registry
from brdfcodec.models.registry import (
    MODEL_ENTRY_POINTS,
    RETIRED_MODELS,
    ModelRegistry,
    default_model_folder,
    find_model,
    package_model_folder,
)

ROOT = Path(__file__).resolve().parents[1]
LEGACY = ROOT / "packages" / "brdfcodec-legacy-models"
LEGACY_MODELS = LEGACY / "brdfcodec_legacy_models" / "models"
#: PyPI's default file limit is 100 MB; issue 52 asks for at most 40.
MAX_WHEEL_BYTES = 40_000_000


def test_the_wheel_ships_one_model() -> None:
    package_data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    models = [pattern for pattern in package_data["brdfcodec"] if pattern.startswith("data/models")]
    assert models == ["data/models/default/*"]
    folders = [p.name for p in (ROOT / "brdfcodec" / "data" / "models").iterdir() if (p / "model.json").exists()]
    assert folders == ["default"]


def test_the_legacy_package_holds_the_retired_models_and_names_its_entry_point() -> None:
    project = tomllib.loads((LEGACY / "pyproject.toml").read_text())
    assert project["project"]["entry-points"][MODEL_ENTRY_POINTS] == {"legacy": "brdfcodec_legacy_models:models_folder"}
    assert project["tool"]["setuptools"]["package-data"]["brdfcodec_legacy_models"] == ["models/*/*"]
    held = {json.loads(p.read_text())["decoder_sha256"]: json.loads(p.read_text())["name"]
            for p in LEGACY_MODELS.glob("*/model.json")}
    assert held == RETIRED_MODELS


@pytest.fixture()
def bare(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A process that has only the wheel: no registered folder, no model path, no model package installed."""
    monkeypatch.setattr(registry, "_PROCESS_REGISTRY", ModelRegistry())
    monkeypatch.delenv("BRDFCODEC_MODEL_PATH", raising=False)
    monkeypatch.setenv("BRDFCODEC_CONFIG_DIR", str(tmp_path / "config"))
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda **kwargs: [])


def _old_file(path: Path, sha: str) -> Path:
    write_bvae(path, [LatentRecord("gold", np.zeros(8), np.full(8, 0.2))], DecoderReference(sha, RETIRED_MODELS[sha]))
    return path


@pytest.mark.parametrize("sha", sorted(RETIRED_MODELS))
def test_an_old_file_without_the_legacy_models_names_the_fix(bare, tmp_path: Path, capsys, sha: str) -> None:
    old = _old_file(tmp_path / "old.bvae", sha)
    assert main(["decompress", str(old), "-o", str(tmp_path / "x.npy")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("bvae decompress: error: ")
    assert RETIRED_MODELS[sha] in err and "pip install packages/brdfcodec-legacy-models" in err
    assert "BRDFCODEC_MODEL_PATH" in err and "Traceback" not in err
    assert not (tmp_path / "x.npy").exists()
    with pytest.raises(ModelNotFoundError, match="brdfcodec-legacy-models"):
        package_model_folder(RETIRED_MODELS[sha].removeprefix("bvae-"))


def test_the_default_needs_no_legacy_package(bare) -> None:
    shipped = json.loads((default_model_folder() / "model.json").read_text())["decoder_sha256"]
    assert find_model(shipped).folder == default_model_folder()


def test_the_installed_package_is_found_through_its_entry_point(bare, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(LEGACY))
    declared = tomllib.loads((LEGACY / "pyproject.toml").read_text())["project"]["entry-points"][MODEL_ENTRY_POINTS]
    points = [importlib.metadata.EntryPoint(name, value, MODEL_ENTRY_POINTS) for name, value in declared.items()]
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group=None, **kwargs: points if group == MODEL_ENTRY_POINTS else [])
    for sha, name in RETIRED_MODELS.items():
        manifest = find_model(sha)
        assert manifest.name == name and manifest.folder.parent == LEGACY_MODELS
    assert package_model_folder("nbrdf-proxy-small-v1").parent == LEGACY_MODELS


def test_the_path_variable_is_enough(bare, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(LEGACY_MODELS))
    for sha, name in RETIRED_MODELS.items():
        assert find_model(sha).name == name


def test_a_model_package_that_fails_breaks_nothing(bare, monkeypatch: pytest.MonkeyPatch) -> None:
    points = [importlib.metadata.EntryPoint("broken", "no_such_module_here:models_folder", MODEL_ENTRY_POINTS)]
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group=None, **kwargs: points if group == MODEL_ENTRY_POINTS else [])
    shipped = json.loads((default_model_folder() / "model.json").read_text())["decoder_sha256"]
    with pytest.warns(UserWarning, match="no_such_module_here"):
        assert find_model(shipped).folder == default_model_folder()


@pytest.mark.slow
def test_the_wheel_is_at_most_40_mb(tmp_path: Path) -> None:
    """Builds the wheel (``pip wheel . --no-deps``): under a minute."""
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "-w", str(tmp_path), "--no-deps",
                    "--no-build-isolation", "-q"], check=True, timeout=600)
    (wheel,) = tmp_path.glob("brdfcodec-*.whl")
    assert wheel.stat().st_size <= MAX_WHEEL_BYTES, f"{wheel.name}: {wheel.stat().st_size:,} bytes"
    with zipfile.ZipFile(wheel) as archive:
        manifests = [name for name in archive.namelist() if name.endswith("/model.json")]
    assert manifests == ["brdfcodec/data/models/default/model.json"]
