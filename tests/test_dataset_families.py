"""Datasets from several sources: each material's family and kind, per-family held-out split, the CLI."""

from __future__ import annotations

import zipfile
from pathlib import Path

import h5py
import pytest

from brdfcodec.cli import main
from brdfcodec.datasets.hdf5 import MIXED_SOURCE_KIND, BrdfDataset, build_dataset
from brdfcodec.datasets.nbrdf import nbrdf_zip_family
from brdfcodec.datasets.sources import analytic_sources, merl_folder_sources
from brdfcodec.datasets.split import TRAIN, VALIDATION, split_by_family, split_materials
from brdfcodec.io.merl import write_merl


def test_split_by_family_holds_out_each_family() -> None:
    names = [f"m{i}" for i in range(40)] + [f"r{i}" for i in range(10)]
    families = ["merl"] * 40 + ["rgl"] * 10
    split = split_by_family(names, families, validation_fraction=0.2, seed=3)
    assert sum(s == VALIDATION for s, f in zip(split, families, strict=True) if f == "merl") == 8
    assert sum(s == VALIDATION for s, f in zip(split, families, strict=True) if f == "rgl") == 2
    # One family alone splits exactly as before (datasets of one family keep their split).
    assert split[:40] == split_materials(names[:40], validation_fraction=0.2, seed=3)
    # Independent of order.
    order = list(reversed(range(50)))
    again = split_by_family([names[i] for i in order], [families[i] for i in order], validation_fraction=0.2, seed=3)
    assert [again[order.index(i)] for i in range(50)] == split
    with pytest.raises(ValueError, match="families"):
        split_by_family(names, families[:-1])


@pytest.fixture(scope="module")
def merl_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("merl-folder")
    for source in analytic_sources(["red-plastic", "gold", "chrome"], random_count=1):
        write_merl(folder / f"{source.name}.binary", source.load().brdf)
    return folder


@pytest.mark.slow
def test_mixed_dataset_records_family_and_kind(merl_folder: Path, tmp_path: Path) -> None:
    presets = ["white-matte", "black-obsidian", "green-satin", "blue-rubber"]
    sources = merl_folder_sources(merl_folder) + analytic_sources(presets)
    out = tmp_path / "mixed.h5"
    build_dataset(out, sources, description="two families", validation_fraction=0.3, include_tables=False,
                  progress=False)
    with BrdfDataset(out) as dataset:
        assert dataset.source_kind == MIXED_SOURCE_KIND
        assert dataset.families == ["merl"] * 4 + ["analytic"] * 4
        assert dataset.source_kinds == ["merl"] * 4 + ["analytic"] * 4
        for family in ("merl", "analytic"):
            held_out = dataset.indices(VALIDATION, family=family)
            assert len(held_out) == 1, family  # round(0.3 · 4) in each family
            assert len(dataset.indices(TRAIN, family=family)) == 3
        with pytest.raises(ValueError, match="no family 'rgl'"):
            dataset.indices(family="rgl")


@pytest.mark.slow
def test_duplicate_names_across_sources_are_refused(merl_folder: Path, tmp_path: Path) -> None:
    sources = merl_folder_sources(merl_folder) + analytic_sources(["gold"])
    with pytest.raises(ValueError, match="two sources give the material name 'gold'"):
        build_dataset(tmp_path / "dup.h5", sources, description="x", progress=False)
    assert not (tmp_path / "dup.h5").exists()


def test_datasets_without_families_read_as_one_family(merl_folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "old.h5"
    build_dataset(out, merl_folder_sources(merl_folder), description="x", include_tables=False, progress=False)
    with h5py.File(out, "a") as handle:  # as written before per-material families existed
        del handle["families"], handle["source_kinds"]
        handle.attrs["source_kind"] = "nbrdf-proxy"
    with BrdfDataset(out) as dataset:
        assert dataset.families == ["merl"] * 4
        assert dataset.source_kinds == ["nbrdf-proxy"] * 4


@pytest.mark.slow
def test_cli_builds_from_several_sources(merl_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "measured"
    folder.mkdir()
    for source in analytic_sources([], random_count=2, seed=5):
        write_merl(folder / f"measured-{source.name}.binary", source.load().brdf)
    merl_folder = folder  # names distinct from the analytic presets
    out = tmp_path / "cli.h5"
    code = main(["dataset", "build", "--merl", str(merl_folder), "--analytic", "--materials", "gold,chrome",
                 "-o", str(out), "--quiet", "--no-tables"])
    assert code == 1  # --materials does not apply to folders
    assert "--materials applies to" in capsys.readouterr().err
    code = main(["dataset", "build", "--merl", str(merl_folder), "--analytic",
                 "-o", str(out), "--quiet", "--no-tables"])
    assert code == 0, capsys.readouterr().err
    assert "families analytic, merl" in capsys.readouterr().out
    with BrdfDataset(out) as dataset:
        assert set(dataset.families) == {"merl", "analytic"}
        assert "MERL .binary files" in dataset.description and "analytic" in dataset.description
    assert main(["dataset", "build", "-o", str(tmp_path / "none.h5")]) == 2
    assert "at least one source" in capsys.readouterr().err


def test_nbrdf_archive_family(tmp_path: Path) -> None:
    for folder, expected in (("rgl-nbrdf", "rgl"), ("merl-nbrdf", "merl")):
        archive = tmp_path / f"{folder}-x.zip"
        with zipfile.ZipFile(archive, "w") as handle:
            handle.writestr(f"{folder}/a.h5", b"")
            handle.writestr(f"{folder}/LICENSE", b"")
        assert nbrdf_zip_family(archive) == expected
    flat = tmp_path / "my-fits.zip"
    with zipfile.ZipFile(flat, "w") as handle:
        handle.writestr("a.h5", b"")
    assert nbrdf_zip_family(flat) == "my-fits"


@pytest.mark.shared
def test_both_proxy_archives_give_two_families(shared_dir: Path) -> None:
    data = shared_dir / "data"
    assert nbrdf_zip_family(data / "merl-nbrdf-90.zip") == "merl"
    if (data / "rgl-nbrdf-30.zip").is_file():
        assert nbrdf_zip_family(data / "rgl-nbrdf-30.zip") == "rgl"


@pytest.mark.slow
def test_records_encoded_from_a_dataset_keep_the_sources_provenance(tmp_path: Path) -> None:
    """A dataset row of an RGL measurement encodes (with --provenance) to the same source_kind and source_sha256 as its file would."""
    from dataclasses import replace

    from brdfcodec.datasets.sources import LoadedMaterial, MaterialSource
    from brdfcodec.format.bvae import read_bvae
    from brdfcodec.io.rgl import RGL_SOURCE_KIND

    (gold,) = analytic_sources(["gold"])
    (chrome,) = analytic_sources(["chrome"])
    bsdf_sha = "5" * 64  # stands for the .bsdf file's hash, as read_rgl_bsdf sets it
    table = replace(chrome.load().brdf, source_kind=RGL_SOURCE_KIND, source_sha256=bsdf_sha)
    rgl = MaterialSource("paper", "paper_rgb.bsdf", lambda: LoadedMaterial(table, bsdf_sha), "rgl", RGL_SOURCE_KIND)
    out = tmp_path / "two.h5"
    build_dataset(out, [gold, rgl], description="x", validation_fraction=0.0, progress=False)
    with BrdfDataset(out) as dataset:
        rows = [dataset.table(i) for i in range(2)]
    assert [r.source_kind for r in rows] == [None, RGL_SOURCE_KIND]
    assert rows[0].source_sha256 == gold.load().source_sha256 and rows[1].source_sha256 == bsdf_sha
    bvae = tmp_path / "two.bvae"
    assert main(["compress", str(out), "-o", str(bvae), "--effort", "0", "--provenance"]) == 0
    meta = {r.name: r.meta for r in read_bvae(bvae).records}
    assert meta["paper"]["source_kind"] == RGL_SOURCE_KIND and meta["paper"]["source_sha256"] == bsdf_sha
    assert "source_kind" not in meta["gold"] and meta["gold"]["source_sha256"] == rows[0].source_sha256
    assert "relae" in meta["paper"]


def test_fold_by_family_is_stratified_complete_and_order_free() -> None:
    from brdfcodec.datasets.split import fold_by_family

    names = [f"m{i}" for i in range(90)] + [f"r{i}" for i in range(30)]
    families = ["merl"] * 90 + ["rgl"] * 30
    folds = fold_by_family(names, families, folds=4, seed=0)
    for fold in range(4):
        merl = sum(1 for f, fam in zip(folds, families, strict=True) if f == fold and fam == "merl")
        rgl = sum(1 for f, fam in zip(folds, families, strict=True) if f == fold and fam == "rgl")
        assert merl in (22, 23) and rgl in (7, 8)
    order = list(reversed(range(120)))
    again = fold_by_family([names[i] for i in order], [families[i] for i in order], folds=4, seed=0)
    assert [again[order.index(i)] for i in range(120)] == folds
    assert fold_by_family(names, families, folds=4, seed=1) != folds
    with pytest.raises(ValueError, match="at least 2"):
        fold_by_family(names, families, folds=1)
