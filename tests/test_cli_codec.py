"""``bvae compress | decompress | extract | info`` on .bvae files: round trips, outputs, refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.cli import main
from brdfcodec.format.bvae import FORMAT_MAJOR, read_bvae
from brdfcodec.io.exr import read_exr_rgb
from brdfcodec.io.merl import MerlBRDF, read_merl, write_merl


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture()
def merl_folder(tmp_path: Path, analytic_tables: dict[str, MerlBRDF]) -> Path:
    folder = tmp_path / "merl"
    folder.mkdir()
    for name in ("gold", "chrome", "red-plastic"):
        write_merl(folder / f"{name}.binary", analytic_tables[name])
    return folder


@pytest.fixture(autouse=True)
def tiny_model_registered(tiny_model_folder: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(tiny_model_folder))


@pytest.mark.slow
def test_compress_decompress_round_trip(capsys, merl_folder: Path, tmp_path: Path, tiny_model_folder: Path) -> None:
    lib = tmp_path / "lib.bvae"
    code, out, err = run(capsys, "compress", str(merl_folder), "-o", str(lib), "--model", str(tiny_model_folder))
    assert code == 0, err
    assert "RelAE mapped" in out and "3 materials" in out and "bytes per material" in out
    library = read_bvae(lib)
    assert library.header.names == ["chrome", "gold", "red-plastic"]
    assert all(not r.meta for r in library.records)  # RelAE printed, not stored: provenance is opt-in

    code, out, err = run(capsys, "info", str(lib))
    assert code == 0, err
    # the lowest version that holds it: short references (2.6; without them, a latent without σ: 2.2)
    assert "tiny-test-model" in out and f"format {FORMAT_MAJOR}.6" in out and "gold" in out

    kept = tmp_path / "kept.bvae"
    code, out, err = run(capsys, "compress", str(merl_folder), "-o", str(kept), "--model", str(tiny_model_folder),
                         "--provenance")
    assert code == 0, err
    assert all("relae" in r.meta and "source_sha256" in r.meta for r in read_bvae(kept).records)
    assert kept.stat().st_size > lib.stat().st_size

    code, _, err = run(capsys, "decompress", str(lib), "--material", "gold", "-o", str(tmp_path / "gold.binary"),
                       "--reference", str(merl_folder / "gold.binary"))
    assert code == 0, err
    decoded = read_merl(tmp_path / "gold.binary")
    assert decoded.values.shape == (3, 90, 90, 180) and np.isfinite(decoded.values).all()

    code, _, err = run(capsys, "decompress", str(lib), "-o", str(tmp_path / "all"), "--format", "npy")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "all").iterdir()) == ["chrome.npy", "gold.npy", "red-plastic.npy"]
    np.testing.assert_array_equal(np.load(tmp_path / "all" / "gold.npy"), decoded.values.astype(np.float32))

    code, _, err = run(capsys, "decompress", str(lib), "--material", "gold", "-o", str(tmp_path / "g.exr"),
                       "--phi-d", "0,90")
    assert code == 0, err
    parts = read_exr_rgb(tmp_path / "g.exr")
    assert sorted(parts) == ["phid000", "phid090"]
    expected = np.maximum(decoded.values[..., 90], 0) * np.array([1.0, 1.15, 1.66])[:, None, None] / 1500
    np.testing.assert_allclose(parts["phid090"], np.moveaxis(expected, 0, -1), rtol=1e-6)


@pytest.mark.slow
def test_extract_copies_records_unchanged(capsys, merl_folder: Path, tmp_path: Path) -> None:
    lib = tmp_path / "lib.bvae"
    assert run(capsys, "compress", str(merl_folder), "-o", str(lib), "--no-measure", "--float16")[0] == 0
    scene = tmp_path / "scene.bvae"
    code, out, err = run(capsys, "extract", str(lib), "--material", "red-plastic", "--material", "chrome",
                         "-o", str(scene))
    assert code == 0, err
    original, extracted = read_bvae(lib), read_bvae(scene)
    assert extracted.header.names == ["red-plastic", "chrome"]
    assert extracted.header.latent_dtype == "float16"
    for record in extracted.records:
        source = original.record(record.name)
        np.testing.assert_array_equal(record.mu, source.mu)
        assert record.meta == source.meta
    code, _, err = run(capsys, "extract", str(lib), "--material", "missing", "-o", str(tmp_path / "x.bvae"))
    assert code == 1 and "missing" in err and not (tmp_path / "x.bvae").exists()


@pytest.mark.slow
def test_refusals_leave_nothing_behind(capsys, merl_folder: Path, tmp_path: Path) -> None:
    lib = tmp_path / "lib.bvae"
    assert run(capsys, "compress", str(merl_folder / "gold.binary"), "-o", str(lib))[0] == 0
    before = lib.read_bytes()
    code, _, err = run(capsys, "compress", str(merl_folder / "gold.binary"), "-o", str(lib))
    assert code == 1 and "--force" in err and lib.read_bytes() == before

    corrupt = tmp_path / "corrupt.bvae"
    data = bytearray(before)
    data[-3] ^= 0x10
    corrupt.write_bytes(bytes(data))
    code, _, err = run(capsys, "decompress", str(corrupt), "-o", str(tmp_path / "out.binary"))
    assert code == 1 and "CRC-32" in err and "Traceback" not in err
    assert not (tmp_path / "out.binary").exists()

    code, _, err = run(capsys, "decompress", str(lib), "-o", str(tmp_path / "out.txt"))
    assert code == 2 and "must end in one of .binary, .npy, .exr, .bsdf" in err  # a usage error, as every command

    bad = tmp_path / "bad.binary"
    bad.write_bytes(b"\x01\x00\x00\x00" * 5)
    code, _, err = run(capsys, "compress", str(bad), "-o", str(tmp_path / "bad.bvae"))
    assert code == 1 and "bad.binary" in err and not (tmp_path / "bad.bvae").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.binary", "corrupt.bvae", "lib.bvae", "merl"]


def test_missing_decoder_names_the_hashes(capsys, merl_folder: Path, tmp_path: Path,
                                          tiny_model_folder: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    lib = tmp_path / "lib.bvae"
    assert run(capsys, "compress", str(merl_folder / "gold.binary"), "-o", str(lib), "--model",
               str(tiny_model_folder), "--no-measure")[0] == 0
    monkeypatch.delenv("BRDFCODEC_MODEL_PATH")
    code, out, _ = run(capsys, "info", "--json", str(lib))
    assert code == 0 and json.loads(out)["decoder"]["installed_at"] is None
    code, _, err = run(capsys, "decompress", str(lib), "-o", str(tmp_path / "x.binary"))
    sha = read_bvae(lib).header.decoder.sha256
    assert code == 1 and sha in err and "available" in err


def test_model_register_persists_for_later_processes(capsys, tiny_model_folder: Path, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("BRDFCODEC_MODEL_PATH")
    monkeypatch.setenv("BRDFCODEC_CONFIG_DIR", str(tmp_path / "config"))
    code, out, _ = run(capsys, "model", "list")
    assert code == 0 and "tiny-test-model" not in out
    code, out, err = run(capsys, "model", "register", str(tiny_model_folder))
    assert code == 0, err
    assert (tmp_path / "config" / "model-folders.txt").read_text().strip() == str(tiny_model_folder.resolve())
    code, out, _ = run(capsys, "model", "list")
    assert "tiny-test-model" in out and "bvae-nbrdf-proxy-small-v1" in out
    code, _, err = run(capsys, "model", "register", str(tmp_path))
    assert code == 1 and "model.json" in err


def test_bvae_info_does_not_import_torch(tmp_path: Path) -> None:
    import subprocess
    import sys

    from brdfcodec.format.bvae import DecoderReference, LatentRecord, write_bvae

    path = tmp_path / "x.bvae"
    write_bvae(path, [LatentRecord("a", np.zeros(8), np.ones(8))], DecoderReference("c" * 64, "elsewhere"))
    code = ("import sys; from brdfcodec.cli import main; rc = main(['info', sys.argv[1]]); "
            "assert 'torch' not in sys.modules, 'torch was imported'; sys.exit(rc)")
    result = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "NOT INSTALLED" in result.stdout
