"""Model folders and checkpoints from elsewhere (issue 49; red-team R3-02, R3-06, R3-07, R3-18, R3-19).

Every crafted folder is made here from a tiny exported model: no pickle runs, no network is built for a config
outside its bounds or unlike its weights', no file outside the folder or other than a regular file is read,
and every refusal is a typed error that names the file.
"""

from __future__ import annotations

import ast
import json
import os
import pickle
import shutil
import struct
import sys
import time
from pathlib import Path

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from brdfcodec.cli.main import build_parser, main
from brdfcodec.errors import BrdfcodecError, CheckpointError, ModelChecksumError, ModelFolderError
from brdfcodec.io.hashing import sha256_of_file
from brdfcodec.models import store
from brdfcodec.models.registry import available_models, default_model_folder, find_model
from brdfcodec.models.store import load_model
from brdfcodec.training.checkpoint import load_checkpoint

PACKAGE = Path(__file__).resolve().parents[1] / "brdfcodec"


# --- R3-02: no pickle runs ------------------------------------------------------------------------------------


class _Payload:
    """Unpickled in full, this creates the marker file (``open(marker, "w")``)."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self) -> tuple[object, tuple[str, str]]:
        return open, (self.marker, "w")


def _evil_run(folder: Path) -> Path:
    folder.mkdir()
    marker = folder / "CODE_RAN_MARKER"
    for name in ("best.pt", "checkpoint.pt"):
        (folder / name).write_bytes(pickle.dumps({"model": _Payload(marker)}, protocol=2))
    (folder / "run.json").write_text(json.dumps({"dataset": "none.h5"}))
    return marker


def test_the_payload_runs_when_unpickled_in_full(tmp_path: Path) -> None:
    """The test's own check: the payload is live (so the tests below could see it run)."""
    marker = _evil_run(tmp_path / "run")
    pickle.loads((tmp_path / "run" / "best.pt").read_bytes())
    assert marker.exists()


def test_export_of_a_run_whose_best_pt_runs_code_fails_without_running_it(tmp_path: Path, capsys) -> None:
    marker = _evil_run(tmp_path / "run")
    code = main(["model", "export", str(tmp_path / "run"), "-o", str(tmp_path / "out"), "--name", "x"])
    err = capsys.readouterr().err
    assert code == 1
    assert not marker.exists()
    assert err.startswith("bvae model: error: ")  # R3-18: not "bvae : error"
    assert "best.pt" in err and "refused unread" in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_resume_reads_a_checkpoint_without_running_it(tmp_path: Path) -> None:
    marker = _evil_run(tmp_path / "run")
    with pytest.raises(CheckpointError, match="checkpoint.pt.*refused unread"):
        load_checkpoint(tmp_path / "run" / "checkpoint.pt", required={"model": dict})
    assert not marker.exists()


def test_a_real_checkpoint_with_optimiser_state_loads(tmp_path: Path) -> None:
    model = torch.nn.Linear(3, 2)
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-3)
    model(torch.ones(1, 3)).sum().backward()
    optimizer.step()
    torch.save({"model": model.state_dict(), "optimizer": optimizer.state_dict(), "epoch": 3, "best": float("inf"),
                "best_epoch": 0, "step": 7}, tmp_path / "checkpoint.pt")
    state = load_checkpoint(tmp_path / "checkpoint.pt", required={"model": dict, "epoch": int, "best": (int, float)})
    assert state["epoch"] == 3 and torch.equal(state["model"]["weight"], model.state_dict()["weight"])
    with pytest.raises(CheckpointError, match="lacks 'model_config'"):
        load_checkpoint(tmp_path / "checkpoint.pt", required={"model_config": str})
    with pytest.raises(CheckpointError, match="'epoch' is a int"):
        load_checkpoint(tmp_path / "checkpoint.pt", required={"epoch": str})


def test_a_file_that_is_no_checkpoint_is_a_typed_error(tmp_path: Path) -> None:
    (tmp_path / "best.pt").write_bytes(b"not a pickle")
    with pytest.raises(CheckpointError, match="best.pt"):
        load_checkpoint(tmp_path / "best.pt", required={})


def test_every_torch_load_in_the_package_is_weights_only() -> None:
    calls = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "load" \
                    and isinstance(node.func.value, ast.Name) and node.func.value.id == "torch":
                safe = any(k.arg == "weights_only" and isinstance(k.value, ast.Constant) and k.value.value is True
                           for k in node.keywords)
                calls.append((f"{path.relative_to(PACKAGE)}:{node.lineno}", safe))
    assert calls, "the scan found no torch.load call at all"
    assert [where for where, safe in calls if not safe] == []


def test_export_command_option_keeps_the_subcommand_name() -> None:
    args = build_parser().parse_args(["model", "export", "r", "-o", "o", "--name", "x", "--command", "bvae train"])
    assert args.command == "model" and args.reproduce == "bvae train"


# --- R3-06 and R3-07: model folders checked before anything is built --------------------------------------------


@pytest.fixture()
def model(tiny_model_folder: Path, tmp_path: Path) -> Path:
    """A private copy of the tiny model, to be broken by each test."""
    folder = tmp_path / "m"
    shutil.copytree(tiny_model_folder, folder)
    return folder


def _manifest(folder: Path) -> dict:
    return json.loads((folder / "model.json").read_text())


def _put(folder: Path, manifest: dict) -> None:
    (folder / "model.json").write_text(json.dumps(manifest))


def _rewrite_decoder(folder: Path, change) -> None:
    """Rewrite the decoder's tensors (metadata kept) and name the new hash in model.json."""
    path = folder / "decoder.safetensors"
    with safe_open(str(path), "pt") as opened:
        metadata = opened.metadata()
    tensors = change(load_file(str(path)))
    path.unlink()
    save_file(tensors, str(path), metadata=metadata)
    manifest = _manifest(folder)
    manifest["decoder_sha256"] = sha256_of_file(path)
    _put(folder, manifest)


def _refused(folder: Path, match: str, error: type[BrdfcodecError] = ModelFolderError) -> None:
    start = time.perf_counter()
    with pytest.raises(error, match=match) as caught:
        load_model(folder)
    assert str(folder) in str(caught.value)
    assert time.perf_counter() - start < 3.0


def test_the_untouched_copy_loads(model: Path) -> None:
    encoder, decoder, manifest = load_model(model)
    assert encoder is not None and decoder is not None and manifest.folder == model


@pytest.mark.parametrize(("key", "value", "match"), [
    ("decoder_fc", [40_000_000], r"decoder_fc must be in \[1, 16384\]"),
    ("decoder_res_blocks", 3000, "decoder_res_blocks must be in"),
    ("decoder_res_blocks", -1, "decoder_res_blocks must be in"),
    ("latent_dim", "8", "latent_dim must be an integer"),
    ("latent_dim", 8.5, "latent_dim must be an integer"),
    ("latent_dim", True, "latent_dim must be an integer"),
    ("decoder_fc", "abc", "decoder_fc must be a list"),
    ("decoder_fc", [1.5], "decoder_fc must be an integer"),
    ("decoder_fc", [-5], "decoder_fc must be in"),
    ("decoder_fc", [8] * 9, "decoder_fc must hold 0 to 8"),
    ("decoder_channels", [8, 8], "decoder_channels must hold 3"),
    ("norm", "x", "norm must be"),
    ("negative_slope", "x", "negative_slope must be a number"),
    ("negative_slope", 5.0, "negative_slope must be a number"),
    ("linear_basis", "yes", "linear_basis must be true or false"),
])
def test_a_config_outside_the_schema_is_refused_before_anything_is_built(model: Path, key, value, match) -> None:
    manifest = _manifest(model)
    manifest["config"][key] = value
    _put(model, manifest)
    _refused(model, match)


@pytest.mark.parametrize(("key", "value"), [("negative_slope", 0.9), ("latent_dim", 9), ("decoder_res_blocks", 2)])
def test_a_config_unlike_the_one_in_the_weights_is_refused(model: Path, key, value) -> None:
    """R3-07: the config in the weights' metadata is covered by their hash; model.json cannot change it."""
    manifest = _manifest(model)
    manifest["config"][key] = value
    _put(model, manifest)
    _refused(model, f"config differs from the one stored in the weights.*{key}")


def test_a_swapped_decoder_is_refused(model: Path) -> None:
    manifest = _manifest(model)
    manifest["decoder_sha256"] = "0" * 64
    _put(model, manifest)
    _refused(model, "differs from the manifest", ModelChecksumError)


@pytest.mark.parametrize("target", ["/dev/zero", "outside"])
def test_weights_linked_to_outside_the_folder_are_not_read(model: Path, tmp_path: Path, target: str) -> None:
    if target == "outside":
        outside = tmp_path / "secret.txt"
        outside.write_text("root:x:0:0\n")
        target = str(outside)
    elif not Path(target).exists():
        pytest.skip(f"{target} does not exist here")
    (model / "decoder.safetensors").unlink()
    os.symlink(target, model / "decoder.safetensors")
    _refused(model, "outside its folder")


def test_a_link_inside_the_folder_is_read(model: Path) -> None:
    (model / "decoder.safetensors").rename(model / "weights.bin")
    os.symlink("weights.bin", model / "decoder.safetensors")
    assert load_model(model, parts=("decoder",))[1] is not None


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_fifo_is_not_read(model: Path) -> None:
    (model / "decoder.safetensors").unlink()
    os.mkfifo(model / "decoder.safetensors")
    _refused(model, "not a regular file")


def test_a_manifest_linked_outside_is_not_read(model: Path, tmp_path: Path) -> None:
    outside = tmp_path / "hostname"
    outside.write_text(json.dumps(_manifest(model)))
    (model / "model.json").unlink()
    os.symlink(outside, model / "model.json")
    _refused(model, "outside its folder")


def test_weights_larger_than_the_limit_are_not_read(model: Path, monkeypatch) -> None:
    monkeypatch.setattr(store, "MAX_WEIGHT_BYTES", 1024)
    _refused(model, "more than the 1,024 accepted")


@pytest.mark.parametrize(("text", "match"), [
    (b"[" * 100_000 + b"]" * 100_000, "nested deeper than 32"),
    (b"[]", "a manifest is a JSON object"),
    (b'{"name":"\xff"}', "not a valid model manifest"),
    (b" " * (9 << 20), "more than the"),
])
def test_a_manifest_that_is_no_object_or_too_large_or_deep_is_refused(model: Path, text: bytes, match: str) -> None:
    (model / "model.json").write_bytes(text)
    _refused(model, match)


@pytest.mark.parametrize(("key", "value", "match"), [
    ("name", None, "name must be a string"),
    ("info", [1, 2], "info must be a JSON object"),
    ("parameters", "abc", "parameters must be a JSON object"),
    ("decoder_sha256", "ABC", "decoder_sha256 must be 64 lower-case hex"),
    ("basis_sha256", 5, "basis_sha256 must be 64 lower-case hex"),
])
def test_manifest_fields_of_the_wrong_type_are_refused(model: Path, key, value, match) -> None:
    manifest = _manifest(model)
    manifest[key] = value
    _put(model, manifest)
    _refused(model, match)


def test_nan_in_the_manifest_is_refused(model: Path) -> None:
    text = json.dumps(_manifest(model)).replace('"negative_slope": 0.01', '"negative_slope": NaN')
    assert "NaN" in text
    (model / "model.json").write_text(text)
    _refused(model, "NaN is not a JSON number")


def test_non_finite_weights_are_refused(model: Path) -> None:
    _rewrite_decoder(model, lambda t: {k: torch.full_like(v, float("nan")) if v.is_floating_point() else v
                                       for k, v in t.items()})
    _refused(model, "non-finite values")


def test_reshaped_weights_are_refused_before_the_network_is_built(model: Path) -> None:
    _rewrite_decoder(model, lambda t: {k: v.reshape(-1) if v.ndim > 1 else v for k, v in t.items()})
    _refused(model, "has shape")


def test_missing_tensors_are_refused(model: Path) -> None:
    _rewrite_decoder(model, lambda t: dict(list(t.items())[1:]))
    _refused(model, "not those of the config's network")


@pytest.mark.parametrize("header_size", ["huge", "declared"])
def test_a_malformed_safetensors_header_is_refused(model: Path, header_size: str) -> None:
    path = model / "decoder.safetensors"
    with safe_open(str(path), "pt") as opened:
        metadata = opened.metadata()
    if header_size == "huge":
        data = struct.pack("<Q", 2**63) + b"{}"
    else:  # a tensor of 40 GB declared in a 16-byte body
        header = json.dumps({"__metadata__": metadata,
                             "w": {"dtype": "F32", "shape": [100000, 100000], "data_offsets": [0, 40_000_000_000]}})
        data = struct.pack("<Q", len(header)) + header.encode() + b"\0" * 16
    path.unlink()
    path.write_bytes(data)
    manifest = _manifest(model)
    manifest["decoder_sha256"] = sha256_of_file(path)
    _put(model, manifest)
    _refused(model, "safetensors")


def test_a_basis_linked_to_dev_zero_is_not_read(tmp_path: Path) -> None:
    from brdfcodec.errors import BasisError
    from brdfcodec.layers.basis_storage import load_shared_basis

    if not Path("/dev/zero").exists():
        pytest.skip("/dev/zero does not exist here")
    os.symlink("/dev/zero", tmp_path / "basis.safetensors")
    with pytest.raises(BasisError, match="basis.safetensors: links to /dev/zero, outside its folder"):
        load_shared_basis(tmp_path / "basis.safetensors", "0" * 64)


def test_the_cli_names_the_folder_and_exits_1(model: Path, capsys) -> None:
    manifest = _manifest(model)
    manifest["config"]["decoder_fc"] = [40_000_000]
    _put(model, manifest)
    assert main(["model", "info", str(model)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("bvae model: error: ") and str(model) in err and "Traceback" not in err


# --- R3-19: one broken folder on the search path breaks no other model ------------------------------------------


def test_a_broken_folder_on_the_path_is_skipped_with_a_warning(model: Path, tmp_path: Path, monkeypatch) -> None:
    manifest = _manifest(model)
    manifest["config"]["latent_dim"] = "x"
    _put(model, manifest)
    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(tmp_path))  # tmp_path/m is the broken one
    shipped = json.loads((default_model_folder() / "model.json").read_text())["decoder_sha256"]
    with pytest.warns(UserWarning, match="skipped, not a usable model folder"):
        found = find_model(shipped)
    assert found.folder == default_model_folder()
    with pytest.warns(UserWarning, match=str(model)):
        assert default_model_folder() in [m.folder for m in available_models()]


def test_a_broken_folder_is_the_error_when_it_is_the_one_needed(model: Path, tmp_path: Path, monkeypatch) -> None:
    wanted = _manifest(model)["decoder_sha256"]
    manifest = _manifest(model)
    manifest["config"]["latent_dim"] = "x"
    _put(model, manifest)
    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(tmp_path))
    with pytest.warns(UserWarning), pytest.raises(ModelFolderError, match="latent_dim must be an integer"):
        find_model(wanted)


def test_bvae_model_list_survives_a_broken_folder(model: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    (model / "model.json").write_text("{")
    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(tmp_path))
    assert main(["model", "list"]) == 0
    captured = capsys.readouterr()
    assert str(default_model_folder()) in captured.out
    assert str(model) in captured.err and "skipped" in captured.err


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))


def test_a_basis_tensor_of_a_dtype_numpy_lacks_is_a_typed_error(tmp_path: Path) -> None:
    """Found by the fuzz campaign (reports/fuzz): a basis file whose tensor is bfloat16 made safetensors.numpy
    raise KeyError('BF16'); it is a BasisError naming the file."""
    import hashlib

    from brdfcodec.layers.basis import BasisError
    from brdfcodec.layers.basis_storage import load_shared_basis

    path = tmp_path / "basis.safetensors"
    save_file({"components": torch.zeros((2, 4), dtype=torch.bfloat16),
               "entries": torch.arange(4, dtype=torch.int64)}, str(path))
    sha = hashlib.sha256(path.read_bytes()).hexdigest()
    with pytest.raises(BasisError, match="basis.safetensors: a tensor NumPy cannot read"):
        load_shared_basis(path, sha)
