"""Models by name: ``--model editing`` and ``--model default`` (issue 50: the opt-in editing model).

A model that can be found (registered, on ``$BRDFCODEC_MODEL_PATH``, in an installed model package or shipped)
is also found by its folder's name or by the name its ``model.json`` gives; a path, a hash and an existing folder
keep their meaning. A name no model has is refused with a typed error that lists the names there are.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from brdfcodec.cli.main import main
from brdfcodec.codec.prepare import resolve_model
from brdfcodec.errors import ModelFolderError, ModelNotFoundError
from brdfcodec.models import registry
from brdfcodec.models.registry import (
    EDITING_MODEL_NAME,
    EDITING_SOURCE,
    ModelRegistry,
    default_model_folder,
    find_model_named,
)
from brdfcodec.models.store import load_manifest


@pytest.fixture()
def only(monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    """A process whose findable models are the shipped default and the folders given to the returned function."""
    fresh = ModelRegistry()
    monkeypatch.setattr(registry, "_PROCESS_REGISTRY", fresh)
    monkeypatch.delenv("BRDFCODEC_MODEL_PATH", raising=False)
    monkeypatch.setenv("BRDFCODEC_CONFIG_DIR", str(tmp_path / "config"))
    monkeypatch.setattr(registry, "installed_model_folders", lambda: [])
    return fresh.register


def _copy_of_default(tmp_path: Path, folder_name: str) -> Path:
    copy = tmp_path / folder_name
    shutil.copytree(default_model_folder(), copy)
    return copy


def test_a_model_is_found_by_its_folder_name_and_by_its_manifest_name(only, tmp_path: Path) -> None:
    copy = _copy_of_default(tmp_path, "my-models-editing")
    only(copy)
    assert find_model_named("my-models-editing").folder == copy.resolve()
    shipped = load_manifest(default_model_folder())
    # the copy is registered, so it is searched first, and it carries the default's manifest name
    assert find_model_named(shipped.name).folder == copy.resolve()
    assert find_model_named("default").folder == default_model_folder()
    assert resolve_model("default").decoder_sha256 == shipped.decoder_sha256


def test_an_unknown_name_lists_the_names_there_are(only) -> None:
    with pytest.raises(ModelNotFoundError, match="no model named 'velvet-v9'") as raised:
        resolve_model("velvet-v9")
    assert "default (" in str(raised.value) and "decoder SHA-256" in str(raised.value)


def test_the_editing_model_when_missing_says_how_to_install_it(only) -> None:
    with pytest.raises(ModelNotFoundError) as raised:
        resolve_model(EDITING_MODEL_NAME)
    assert f"pip install {EDITING_SOURCE}" in str(raised.value) and "BRDFCODEC_MODEL_PATH" in str(raised.value)


def test_a_model_folder_in_the_working_directory_wins_over_a_name(only, tmp_path: Path, monkeypatch) -> None:
    copy = _copy_of_default(tmp_path, "velvet")
    monkeypatch.chdir(tmp_path)
    assert Path(resolve_model("velvet").folder).resolve() == copy.resolve()


def test_something_on_disk_that_is_no_model_does_not_hide_a_name(only, tmp_path: Path, monkeypatch) -> None:
    registered = _copy_of_default(tmp_path / "models", "editing")
    only(registered)
    work = tmp_path / "work"
    (work / "editing").mkdir(parents=True)  # a user's folder of edits, say
    monkeypatch.chdir(work)
    assert resolve_model("editing").folder == registered.resolve()
    (work / "velvet").mkdir()  # no model of that name: the folder is read, and its own error raised
    with pytest.raises(ModelFolderError, match="model.json"):
        resolve_model("velvet")


def test_default_is_always_the_shipped_model(only, tmp_path: Path) -> None:
    only(_copy_of_default(tmp_path / "models", "default"))  # registered first in the search order
    assert resolve_model("default").folder == default_model_folder()


def test_a_path_is_never_taken_for_a_name_and_a_bare_name_never_for_a_path(only, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    for path in (str(tmp_path / "editing"), "sub/editing", "./editing"):
        with pytest.raises(ModelFolderError):
            resolve_model(path)
    with pytest.raises(ModelNotFoundError, match="no model named 'mymodel'"):
        resolve_model("mymodel")
    with pytest.raises(ModelNotFoundError, match="empty model reference"):
        resolve_model("")


def test_the_cli_takes_a_name_and_refuses_an_unknown_one(only, tmp_path: Path, red_plastic_file: Path, capsys) -> None:
    out = tmp_path / "gold.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(out), "--model", "default", "--no-measure"]) == 0
    assert out.is_file()
    capsys.readouterr()
    assert main(["compress", str(red_plastic_file), "-o", str(tmp_path / "x.bvae"), "--model", "velvet-v9"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("bvae compress: error: ") and "no model named 'velvet-v9'" in err
    assert "Traceback" not in err and not (tmp_path / "x.bvae").exists()
