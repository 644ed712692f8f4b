"""HDF5 dataset builder and reader, and the deterministic split."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from brdfcodec.conventions import KEPT_PHI_D_SLICES
from brdfcodec.datasets.hdf5 import DATASET_FORMAT_VERSION, BrdfDataset, build_dataset
from brdfcodec.datasets.sources import analytic_sources, merl_folder_sources, nbrdf_zip_sources
from brdfcodec.datasets.split import split_materials
from brdfcodec.errors import DatasetError, MerlFormatError, SourceFormatError
from brdfcodec.io.merl import MerlBRDF, read_merl, write_merl
from brdfcodec.representation import map_values, network_input_from_table


@pytest.fixture(scope="module")
def merl_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("merl-folder")
    for source in analytic_sources(["red-plastic", "gold", "chrome"], random_count=2):
        write_merl(folder / f"{source.name}.binary", source.load().brdf)
    (folder / "notes.txt").write_text("not a table")
    return folder


@pytest.fixture(scope="module")
def merl_dataset(merl_folder: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ds") / "merl.h5"
    build_dataset(out, merl_folder_sources(merl_folder), source_kind="merl", description="test tables",
                  validation_fraction=0.4, seed=1, progress=False)
    return out


@pytest.mark.slow
def test_dataset_holds_inputs_masks_tables_and_provenance(merl_dataset: Path, merl_folder: Path) -> None:
    with BrdfDataset(merl_dataset) as dataset:
        assert len(dataset) == 5
        assert dataset.names == sorted(dataset.names)
        assert dataset.source_kind == "merl" and dataset.description == "test tables"
        assert len(dataset.indices("validation")) == 2 and len(dataset.indices("train")) == 3
        assert dataset.has_tables
        index = dataset.index_of("gold")
        original = read_merl(merl_folder / "gold.binary")
        table = dataset.table(index)
        np.testing.assert_allclose(table.values[original.mask], original.values[original.mask], rtol=1e-6)
        np.testing.assert_array_equal(table.mask, original.mask)
        inputs, masks = dataset.inputs([index])[0], dataset.input_masks([index])[0]
        expected_inputs, expected_masks = network_input_from_table(original.values)
        np.testing.assert_array_equal(inputs, expected_inputs)
        np.testing.assert_array_equal(masks, expected_masks)
        # Channel 21·c + s of the input is colour c at kept slice s, log-mapped.
        slot = 4
        mapped = map_values(original.values)[1, :, :, KEPT_PHI_D_SLICES[slot]]
        ok = original.mask[1, :, :, KEPT_PHI_D_SLICES[slot]]
        np.testing.assert_allclose(inputs[21 + slot][ok], mapped[ok], rtol=1e-6)
        assert (inputs[~masks] == 0).all()
        assert dataset.attribute("format_version") == DATASET_FORMAT_VERSION
        assert list(dataset.attribute("kept_phi_d_slices")) == list(KEPT_PHI_D_SLICES)
    with h5py.File(merl_dataset, "r") as handle:
        digests = [d.decode() for d in handle["source_sha256"][()]]
        assert digests[index] == original.sha256
        assert all(g == b"" for g in handle["genuine_merl"][()])


@pytest.mark.slow
def test_rows_in_any_order(merl_dataset: Path) -> None:
    with BrdfDataset(merl_dataset) as dataset:
        all_inputs = dataset.inputs()
        picked = dataset.inputs([3, 0, 3])
        np.testing.assert_array_equal(picked, all_inputs[[3, 0, 3]])
        assert dataset.inputs([]).shape == (0, 63, 90, 90)


def test_split_is_deterministic_and_order_free() -> None:
    names = [f"mat-{i}" for i in range(90)]
    split = split_materials(names, validation_fraction=0.15, seed=0)
    assert split.count("validation") == 14
    shuffled = names[::-1]
    again = dict(zip(shuffled, split_materials(shuffled, validation_fraction=0.15, seed=0), strict=False))
    assert dict(zip(names, split, strict=False)) == again
    assert split != split_materials(names, validation_fraction=0.15, seed=1)
    # Adding a material moves at most one existing material.
    grown = dict(zip(names + ["new"], split_materials(names + ["new"], validation_fraction=0.15, seed=0), strict=False))
    assert sum(grown[n] != s for n, s in zip(names, split, strict=False)) <= 1
    assert split_materials(["a", "b"], validation_fraction=0.01) .count("validation") == 1
    assert split_materials(["a"], validation_fraction=0.5) == ["train"]
    with pytest.raises(ValueError, match="distinct"):
        split_materials(["a", "a"])
    with pytest.raises(ValueError, match="validation_fraction"):
        split_materials(["a"], validation_fraction=1.0)


def test_bad_source_file_aborts_and_leaves_nothing(merl_folder: Path, tmp_path: Path) -> None:
    folder = tmp_path / "in"
    shutil.copytree(merl_folder, folder)
    (folder / "broken.binary").write_bytes(b"\0" * 100)
    out = tmp_path / "out.h5"
    with pytest.raises(MerlFormatError, match="broken.binary"):
        build_dataset(out, merl_folder_sources(folder), source_kind="merl", description="x", progress=False)
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_materials_loaded_on_several_threads_give_the_same_file(merl_dataset: Path, merl_folder: Path,
                                                                  tmp_path: Path) -> None:
    out = tmp_path / "threads.h5"
    build_dataset(out, merl_folder_sources(merl_folder), source_kind="merl", description="test tables",
                  validation_fraction=0.4, seed=1, progress=False, jobs=3)
    with h5py.File(merl_dataset) as serial, h5py.File(out) as threaded:
        assert set(serial) == set(threaded)
        for key in ("names", "split", "origins", "families", "source_kinds", "source_sha256", "inputs",
                    "input_masks", "tables"):
            assert np.array_equal(serial[key][()], threaded[key][()]), key


def test_a_bad_source_on_several_threads_aborts_in_order_and_leaves_nothing(merl_folder: Path,
                                                                             tmp_path: Path) -> None:
    folder = tmp_path / "in"
    shutil.copytree(merl_folder, folder)
    (folder / "a-broken.binary").write_bytes(b"\0" * 100)  # first in order; the others load beside it
    out = tmp_path / "out.h5"
    with pytest.raises(MerlFormatError, match="a-broken.binary"):
        build_dataset(out, merl_folder_sources(folder), source_kind="merl", description="x", progress=False, jobs=4)
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]
    with pytest.raises(ValueError, match="jobs"):
        build_dataset(out, merl_folder_sources(merl_folder), source_kind="merl", description="x", jobs=0)


def test_folder_errors(tmp_path: Path) -> None:
    with pytest.raises(SourceFormatError, match="no MERL .binary files"):
        merl_folder_sources(tmp_path)
    with pytest.raises(FileNotFoundError):
        merl_folder_sources(tmp_path / "missing")
    (tmp_path / "f").write_text("x")
    with pytest.raises(NotADirectoryError):
        merl_folder_sources(tmp_path / "f")


@pytest.mark.slow
def test_no_tables_option_and_existing_output(tmp_path: Path) -> None:
    out = tmp_path / "small.h5"
    sources = analytic_sources(["white-matte"], random_count=1)
    build_dataset(out, sources, source_kind="analytic", description="x", include_tables=False, progress=False)
    with BrdfDataset(out) as dataset:
        assert not dataset.has_tables
        with pytest.raises(DatasetError, match="without full tables"):
            dataset.table(0)
    with pytest.raises(FileExistsError):
        build_dataset(out, sources, source_kind="analytic", description="x", progress=False)


def test_reader_rejects_foreign_and_future_files(tmp_path: Path, merl_dataset: Path) -> None:
    plain = tmp_path / "plain.h5"
    with h5py.File(plain, "w") as handle:
        handle["x"] = 1
    with pytest.raises(DatasetError, match="not a brdfcodec dataset"):
        BrdfDataset(plain)
    future = tmp_path / "future.h5"
    shutil.copy(merl_dataset, future)
    with h5py.File(future, "r+") as handle:
        handle.attrs["format_version"] = 99
    with pytest.raises(DatasetError, match="version 99"):
        BrdfDataset(future)
    text = tmp_path / "t.h5"
    text.write_text("hello")
    with pytest.raises(DatasetError, match="not an HDF5 file"):
        BrdfDataset(text)
    with pytest.raises(FileNotFoundError):
        BrdfDataset(tmp_path / "missing.h5")


def test_network_inputs_zero_invalid_entries(analytic_tables: dict[str, MerlBRDF]) -> None:
    inputs, masks = network_input_from_table(analytic_tables["chrome"].values)
    assert inputs.dtype == np.float32 and masks.dtype == bool
    assert np.isfinite(inputs).all() and (inputs >= 0).all()
    assert (inputs[~masks] == 0).all()
    assert 0.7 < masks.mean() < 0.8


@pytest.mark.shared
@pytest.mark.slow
def test_proxy_dataset_subset(nbrdf_zip: Path, tmp_path: Path) -> None:
    out = tmp_path / "proxy.h5"
    sources = nbrdf_zip_sources(nbrdf_zip, ["green-acrylic", "brass", "black-obsidian"])
    build_dataset(out, sources, source_kind="nbrdf-proxy", description="NBRDF proxy, not MERL", progress=False)
    with BrdfDataset(out) as dataset:
        assert dataset.source_kind == "nbrdf-proxy"
        assert dataset.names == ["green-acrylic", "brass", "black-obsidian"]
        assert np.isfinite(dataset.inputs()).all()
        assert dataset.table(0).valid_fraction > 0.7
    with pytest.raises(SourceFormatError, match="no material named nope"):
        nbrdf_zip_sources(nbrdf_zip, ["nope"])
