"""Issue 39, 3 and 7: one unit per output type, flags that do not apply refused, usage errors exit 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from brdfcodec.cli import main
from brdfcodec.format.bvae import read_bvae
from brdfcodec.io.exr import SLICE_UNITS, read_exr_attributes, read_exr_rgb
from brdfcodec.io.merl import MerlBRDF, read_merl, write_merl


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture()
def library(capsys, tmp_path: Path, tiny_model_folder: Path, analytic_tables: dict[str, MerlBRDF],
            monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(tiny_model_folder))
    write_merl(tmp_path / "gold.binary", analytic_tables["gold"])
    out = tmp_path / "lib.bvae"
    code, _, err = run(capsys, "compress", str(tmp_path / "gold.binary"), "-o", str(out), "--no-measure",
                       "--model", str(tiny_model_folder))
    assert code == 0, err
    return out


def test_each_output_type_has_one_documented_unit(capsys, library: Path, tmp_path: Path) -> None:
    assert run(capsys, "decompress", str(library), "-o", str(tmp_path / "g.binary"))[0] == 0
    stored = read_merl(tmp_path / "g.binary").values
    code, _, err = run(capsys, "decompress", str(library), "-o", str(tmp_path / "g.npy"))
    assert code == 0, err
    npy = np.load(tmp_path / "g.npy")
    np.testing.assert_array_equal(npy, stored.astype(np.float32))  # .npy: MERL's stored units, as .binary
    assert (npy == -1).any()  # and MERL's unmeasured marker below the horizon
    code, _, err = run(capsys, "decompress", str(library), "-o", str(tmp_path / "g.exr"), "--phi-d", "90")
    assert code == 0, err
    scale = np.array([1.0, 1.15, 1.66])[:, None, None] / 1500  # .exr: reflectance in 1/sr, 0 below the horizon
    expected = np.moveaxis(np.maximum(stored[..., 90], 0) * scale, 0, -1)
    np.testing.assert_allclose(read_exr_rgb(tmp_path / "g.exr")["phid090"], expected, rtol=1e-6)
    assert read_exr_attributes(tmp_path / "g.exr", "brdfcodec_units") == {"phid090": SLICE_UNITS}
    assert "1/sr" in SLICE_UNITS


def test_flags_an_output_type_cannot_honour_are_refused(capsys, library: Path, tmp_path: Path) -> None:
    code, _, err = run(capsys, "decompress", str(library), "-o", str(tmp_path / "g.exr"), "--masked", "unmeasured")
    assert code == 2 and "--masked unmeasured" in err and "1/sr" in err
    code, _, err = run(capsys, "decompress", str(library), "-o", str(tmp_path / "g.binary"), "--phi-d", "0,90")
    assert code == 2 and "--phi-d" in err and "Traceback" not in err
    assert not (tmp_path / "g.exr").exists() and not (tmp_path / "g.binary").exists()
    code, _, err = run(capsys, "decompress", str(library), "-o", str(tmp_path / "z.exr"), "--masked", "zero")
    assert code == 0, err  # what an .exr holds anyway


def test_the_overwrite_error_names_the_cli_flag(capsys, library: Path, tmp_path: Path) -> None:
    target = tmp_path / "g.npy"
    target.write_bytes(b"x")
    code, _, err = run(capsys, "decompress", str(library), "-o", str(target))
    assert code == 1 and "--force" in err and "overwrite=True" not in err
    assert target.read_bytes() == b"x"


def test_a_value_list_may_start_with_a_minus_sign(capsys, library: Path, tmp_path: Path) -> None:
    code, _, err = run(capsys, "edit", "traverse", str(library), "--material", "gold", "--dim", "1",
                       "--values", "-2,0,2", "-o", str(tmp_path / "t.bvae"))
    assert code == 0, err
    assert len(read_bvae(tmp_path / "t.bvae").records) == 3


@pytest.mark.slow
def test_relae_figures_come_with_a_legend_once(capsys, tmp_path: Path, tiny_model_folder: Path,
                                               analytic_tables: dict[str, MerlBRDF],
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    from brdfcodec.cli.legend import RELAE_LEGEND

    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(tiny_model_folder))
    for name in ("gold", "chrome"):
        write_merl(tmp_path / f"{name}.binary", analytic_tables[name])
    lib = tmp_path / "lib.bvae"
    code, out, err = run(capsys, "compress", str(tmp_path / "gold.binary"), str(tmp_path / "chrome.binary"),
                         "-o", str(lib), "--model", str(tiny_model_folder))
    assert code == 0, err
    assert out.count("RelAE mapped") == 2 and out.count(RELAE_LEGEND) == 1
    assert "Read 'mapped'" in RELAE_LEGEND and "README" in RELAE_LEGEND
    code, out, err = run(capsys, "decompress", str(lib), "--material", "gold", "-o", str(tmp_path / "g.binary"),
                         "--reference", str(tmp_path / "gold.binary"))
    assert code == 0, err
    assert out.count(RELAE_LEGEND) == 1
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert "### Reading RelAE" in readme
