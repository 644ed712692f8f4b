"""Issue 12: compact encoder storage (float16 matrices, linear path rebuilt from the decoder), spec/model.md §3."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.models.store import compact_encoder, load_manifest, load_model


@pytest.fixture(scope="module")
def compacted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A tiny model whose linear path is fitted (as in training), exported in full storage, and a compacted copy."""
    import dataclasses

    import torch

    from brdfcodec.models.config import TINY_CONFIG
    from brdfcodec.models.network import BetaVAE, initialise_linear_basis
    from brdfcodec.models.store import export_model

    torch.manual_seed(3)
    config = dataclasses.replace(TINY_CONFIG, linear_basis=True, encoder_fc=(256,))  # an FC layer stored as float16
    model = BetaVAE(config).eval()
    initialise_linear_basis(model, torch.rand(10, 63, 90, 90))
    with torch.no_grad():
        model.encoder.head.weight.normal_(0.0, 0.05)  # a non-linear path that contributes
    full = tmp_path_factory.mktemp("models") / "full"
    export_model(model, full, name="tiny-full", info={"data": "random"})
    small = full.parent / "compact"
    shutil.copytree(full, small)
    compact_encoder(small)
    return full, small


def test_compact_encoder_is_small_and_keeps_the_decoder(compacted) -> None:
    full, small = compacted
    a, b = load_manifest(full), load_manifest(small)
    assert b.encoder_storage == "compact" and a.encoder_storage == "full"
    assert a.decoder_sha256 == b.decoder_sha256 and a.encoder_sha256 != b.encoder_sha256
    assert (small / "decoder.safetensors").read_bytes() == (full / "decoder.safetensors").read_bytes()
    assert (small / "encoder.safetensors").stat().st_size < 0.5 * (full / "encoder.safetensors").stat().st_size


def test_the_shipped_model_is_compact_and_small() -> None:
    from brdfcodec.models.registry import default_model_folder

    folder = default_model_folder()
    assert load_manifest(folder).encoder_storage == "compact"
    for name in ("encoder.safetensors", "decoder.safetensors"):  # issue 12: each ≤ 10 MB
        assert (folder / name).stat().st_size <= 10_000_000, name


def test_compact_encoder_gives_the_same_codes(compacted, analytic_tables) -> None:
    import torch

    from brdfcodec.datasets.hdf5 import material_arrays

    full, small = compacted
    inputs, masks = zip(*(material_arrays(t) for t in analytic_tables.values()), strict=True)
    x = torch.from_numpy(np.stack(inputs))
    (enc_a, _, _), (enc_b, _, _) = load_model(full, parts=("encoder",)), load_model(small, parts=("encoder",))
    with torch.no_grad():
        (mu_a, lv_a), (mu_b, lv_b) = enc_a(x), enc_b(x)
    assert torch.allclose(mu_a, mu_b, atol=5e-3, rtol=0)  # float16 rounding of the FC layer and the basis
    assert torch.allclose(lv_a, lv_b, atol=5e-3, rtol=0)
    assert not torch.equal(mu_a, mu_b)  # it is a different file, not a copy


def test_a_compact_encoder_needs_its_decoder(compacted) -> None:
    from brdfcodec.models.store import ModelChecksumError

    _, small = compacted
    broken = small.parent / "broken"
    shutil.copytree(small, broken)
    data = bytearray((broken / "decoder.safetensors").read_bytes())
    data[-1] ^= 1
    (broken / "decoder.safetensors").write_bytes(bytes(data))
    with pytest.raises(ModelChecksumError, match="decoder.safetensors"):
        load_model(broken, parts=("encoder",))


def test_a_renamed_copy_decodes_as_the_original_under_a_new_hash(tmp_path) -> None:
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import LatentRecord
    from brdfcodec.models.registry import default_model_folder
    from brdfcodec.models.store import load_manifest
    from brdfcodec.training.export import copy_renamed

    original = load_manifest(default_model_folder())
    copy = copy_renamed(default_model_folder(), tmp_path / "renamed", "bvae-renamed")
    assert copy.name == "bvae-renamed" and copy.decoder_sha256 != original.decoder_sha256
    assert copy.basis_sha256 == original.basis_sha256 and copy.info["errors"] == original.info["errors"]
    assert "# Model card: bvae-renamed" in (tmp_path / "renamed" / "MODEL_CARD.md").read_text()
    record = LatentRecord("probe", np.linspace(-1, 1, 8).astype(np.float32), np.ones(8))
    np.testing.assert_array_equal(BrdfDecoder(tmp_path / "renamed").mapped_record(record),
                                  BrdfDecoder(default_model_folder()).mapped_record(record))
    with pytest.raises(FileExistsError):
        copy_renamed(default_model_folder(), tmp_path / "renamed", "again")


def test_an_interrupted_compaction_leaves_the_folder_as_it_was(compacted, tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A crash after the new encoder file is written and before model.json names its hash: the folder is the old
    one, whole (its hashes verify), with nothing left beside it."""
    from brdfcodec.models import store

    full, _ = compacted
    folder = tmp_path / "model"
    shutil.copytree(full, folder)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}

    def crash(out, stored):  # noqa: ANN001, ANN202
        raise KeyboardInterrupt

    monkeypatch.setattr(store, "write_manifest", crash)
    with pytest.raises(KeyboardInterrupt):
        store.compact_encoder(folder)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]
    load_model(folder)
