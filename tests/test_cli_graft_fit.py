"""Issue 39, 6: ``bvae edit graft --fit`` keeps the better record (or says why not) and names grafts one way."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.cli import main
from brdfcodec.edit import latent_edits as edit
from brdfcodec.format.bvae import GraftRecord, LatentRecord, read_bvae
from brdfcodec.io.merl import MerlBRDF, write_merl


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


def _colour_values(library: Path) -> str:
    from brdfcodec.codec import BrdfDecoder

    count = len(BrdfDecoder.for_header(read_bvae(library).header).colour_dims)
    return ",".join(["0.5"] * count)


@pytest.mark.slow
def test_a_graft_is_named_the_same_way_with_values_and_with_fit(capsys, library: Path, tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    code, _, err = run(capsys, "edit", "graft", str(library), "--material", "gold",
                       f"--values={_colour_values(library)}", "-o", str(tmp_path / "v.bvae"))
    assert code == 0, err
    assert read_bvae(tmp_path / "v.bvae").header.names == ["gold.graft"]

    monkeypatch.setattr(edit, "fit_graft", functools.partial(edit.fit_graft, steps=3))  # the real fit, shorter
    code, out, err = run(capsys, "edit", "graft", str(library), "--material", "gold", "--fit",
                         str(tmp_path / "gold.binary"), "-o", str(tmp_path / "f.bvae"))
    assert code == 0, err
    written = read_bvae(tmp_path / "f.bvae").records[0]
    if isinstance(written, GraftRecord):
        assert written.name == "gold.graft"
    else:  # the code alone won, said so, and kept its own name
        assert written.name == "gold" and "no better than the code alone" in err


def test_a_fitted_graft_worse_than_the_code_alone_is_not_written_silently(capsys, library: Path, tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    def worse_fit(decoder, record, inputs, mask, **kwargs) -> GraftRecord:  # a fit that lost (issue: 0.0489 → 0.0507)
        dims = tuple(decoder.colour_dims)
        return GraftRecord(f"{record.name}.graft", record.mu, record.sigma, dims, np.full(len(dims), 3.0, np.float32),
                           {"edit": {"op": "fit-graft"}})

    import brdfcodec.codec as codec

    measured = codec.measure

    def measure_worse(record, decoder, source):  # a graft that measures worse than the code alone, whatever it is
        out = measured(record, decoder, source)
        if isinstance(out, GraftRecord):
            relae = dict(out.meta["relae"], mapped=1.0 + out.meta["relae"]["mapped"])
            out = dataclasses.replace(out, meta={**out.meta, "relae": relae})
        return out

    monkeypatch.setattr(edit, "fit_graft", worse_fit)
    monkeypatch.setattr(codec, "measure", measure_worse)
    code, out, err = run(capsys, "edit", "graft", str(library), "--material", "gold", "--fit",
                         str(tmp_path / "gold.binary"), "-o", str(tmp_path / "f.bvae"))
    assert code == 0, err
    assert "warning" in err and "no better than the code alone" in err
    [written] = read_bvae(tmp_path / "f.bvae").records
    assert isinstance(written, LatentRecord) and not isinstance(written, GraftRecord) and written.name == "gold"
    np.testing.assert_array_equal(written.mu, read_bvae(library).record("gold").mu)
