"""``bvae edit`` and ``bvae render`` from the command line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from brdfcodec.cli import main
from brdfcodec.format.bvae import GraftRecord, read_bvae
from brdfcodec.io.merl import MerlBRDF, write_merl


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture()
def library(capsys, tmp_path: Path, analytic_tables: dict[str, MerlBRDF]) -> Path:
    for name in ("gold", "red-plastic"):
        write_merl(tmp_path / f"{name}.binary", analytic_tables[name])
    out = tmp_path / "lib.bvae"
    code, _, err = run(capsys, "compress", str(tmp_path / "gold.binary"), str(tmp_path / "red-plastic.binary"),
                       "-o", str(out), "--no-measure")
    assert code == 0, err
    return out


def test_edit_operations(capsys, library: Path, tmp_path: Path) -> None:
    code, out, err = run(capsys, "edit", "traverse", str(library), "--material", "gold", "--dim", "4",
                         "--values=-2,0,2", "-o", str(tmp_path / "t.bvae"))
    assert code == 0, err
    steps = read_bvae(tmp_path / "t.bvae").records
    source = read_bvae(library).record("gold")
    np.testing.assert_array_equal(steps[1].mu, source.mu)
    assert steps[2].mu[3] == pytest.approx(source.mu[3] + 2)

    code, _, err = run(capsys, "edit", "interp", str(library), "gold", "red-plastic", "--t", "0,1",
                       "-o", str(tmp_path / "i.bvae"))
    assert code == 0, err
    ends = read_bvae(tmp_path / "i.bvae").records
    np.testing.assert_array_equal(ends[0].mu, source.mu)
    np.testing.assert_array_equal(ends[1].mu, read_bvae(library).record("red-plastic").mu)

    code, _, err = run(capsys, "edit", "graft", str(library), "--material", "gold", "--values=0.5,-0.5",
                       "-o", str(tmp_path / "g.bvae"))
    assert code == 0, err
    grafted = read_bvae(tmp_path / "g.bvae").records[0]
    assert isinstance(grafted, GraftRecord) and grafted.graft_values.tolist() == [0.5, -0.5]

    code, _, err = run(capsys, "edit", "graft", str(library), "--material", "gold", "--values", "1",
                       "-o", str(tmp_path / "bad.bvae"))
    assert code == 2 and "colour dimensions" in err and not (tmp_path / "bad.bvae").exists()
    code, _, err = run(capsys, "edit", "traverse", str(library), "--dim", "1", "-o", str(tmp_path / "x.bvae"))
    assert code == 2 and "--material" in err  # usage errors exit 2 (README)


@pytest.mark.slow
def test_render_outputs(capsys, library: Path, tmp_path: Path) -> None:
    code, out, err = run(capsys, "render", str(library), "--material", "gold", "-o", str(tmp_path / "s.png"),
                         "--size", "48")
    assert code == 0, err
    assert "decode" in out
    from PIL import Image

    sphere = np.asarray(Image.open(tmp_path / "s.png"))
    assert sphere.shape == (48, 48, 3) and sphere[24, 24].max() > 0 and sphere[0, 0].max() == 0
    code, _, err = run(capsys, "render", str(tmp_path / "gold.binary"), "-o", str(tmp_path / "s.exr"),
                       "--size", "32", "--flat")
    assert code == 0, err
    from brdfcodec.io.exr import read_exr_rgb

    [flat] = read_exr_rgb(tmp_path / "s.exr").values()
    assert flat.shape == (32, 32, 3) and np.isfinite(flat).all() and flat.max() > 0
    code, _, err = run(capsys, "render", str(library), "--material", "red-plastic", "--traversal",
                       "-o", str(tmp_path / "sheet.png"), "--size", "96")
    assert code == 0, err
    sheet = np.asarray(Image.open(tmp_path / "sheet.png"))
    assert sheet.shape[0] > 8 * 32 and sheet.shape[1] > 7 * 32
    code, out, err = run(capsys, "render", str(library), "--material", "gold", "-o", str(tmp_path / "c.png"),
                         "--size", "32", "--compare", str(tmp_path / "gold.binary"))
    assert code == 0, err
    assert "ΔE ITP mean" in out and "PSNR" in out
    code, _, err = run(capsys, "render", str(library), "--material", "gold", "-o", str(tmp_path / "s.jpg"))
    assert code == 2 and "png" in err  # a usage error, as every command's output type
