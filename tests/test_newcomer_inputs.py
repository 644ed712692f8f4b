"""What a newcomer hands the commands (issue 52): NBRDF fits read directly, output types checked alike, messages
that say what a file is.

NBRDF fits are made here in the published layout (``tests/nbrdf_files.py``); the shared archive is used where
present (``@pytest.mark.shared``). Compression uses the tiny test model unless a test needs the shipped one.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from nbrdf_files import constant_fit, keras_description, lobe_fit, write_fit_archive, write_fit_files

from brdfcodec.cli import main
from brdfcodec.datasets.hdf5 import HDF5_SIGNATURE
from brdfcodec.errors import MerlFormatError, SourceFormatError
from brdfcodec.format.bvae import read_bvae
from brdfcodec.format.container import MAGIC as BVAE_MAGIC
from brdfcodec.io.file_kinds import sniff_file_kind
from brdfcodec.io.merl import read_merl
from brdfcodec.io.rgl import TENSOR_FILE_MAGIC


@pytest.fixture
def tiny_model(tiny_model_folder: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The tiny test model, findable by its decoder's SHA-256 (so that its files decode)."""
    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(tiny_model_folder))
    return tiny_model_folder


def _compress(inputs: list[Path], out: Path, model: Path, *extra: str) -> int:
    return main(["compress", *map(str, inputs), "-o", str(out), "--model", str(model), "--effort", "0", *extra])


# --- messages: what a file is ------------------------------------------------------------------------------------


def test_file_kinds_follow_the_project_magics() -> None:
    assert "HDF5" in (sniff_file_kind(HDF5_SIGNATURE + b"\0" * 4) or "")
    assert ".bvae" in (sniff_file_kind(BVAE_MAGIC + b"\0" * 4) or "")
    assert "RGL" in (sniff_file_kind(TENSOR_FILE_MAGIC) or "")
    assert sniff_file_kind(np.array([90, 90, 180], "<i4").tobytes()) is None  # a MERL header is no other kind
    # binary bytes whose first one happens to be '[' or '{' are not called JSON text
    assert sniff_file_kind(bytes.fromhex("5b77dc928ce62077a11c574c09bfb044")) is None
    assert sniff_file_kind(b"{\x00\x01\x02") is None


@pytest.mark.parametrize(
    ("content", "kind"),
    [
        (HDF5_SIGNATURE + b"\0" * 64, "an HDF5 file"),
        (b"PK\x03\x04" + b"\0" * 64, "a zip archive"),
        (BVAE_MAGIC + b"\0" * 64, "a .bvae file"),
        (b'{"class_name": "Sequential"}', "a text file (JSON"),
        (b"# notes about materials\n", "a text file"),
        (b"", "an empty file"),
    ],
)
def test_merl_reader_says_what_the_file_is(tmp_path: Path, content: bytes, kind: str) -> None:
    path = tmp_path / "four.h5"
    path.write_bytes(content)
    with pytest.raises(MerlFormatError) as caught:
        read_merl(path)
    message = str(caught.value)
    assert kind in message and "not a MERL" in message or "too short" in message and kind in message
    assert "header gives dimensions" not in message and str(path) in message


def test_merl_reader_keeps_the_dimensions_for_unknown_bytes(tmp_path: Path) -> None:
    path = tmp_path / "other.binary"
    path.write_bytes(np.array([45, 45, 90], "<i4").tobytes() + b"\0" * 64)
    with pytest.raises(MerlFormatError, match=r"header gives dimensions \(45, 45, 90\)"):
        read_merl(path)


def test_reference_that_is_another_hdf5_file_says_so(tmp_path: Path, tiny_model: Path, red_plastic_file: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r.bvae"
    assert _compress([red_plastic_file], out, tiny_model, "--no-measure") == 0
    four = tmp_path / "four.h5"  # an HDF5 file that is no NBRDF fit (a dataset, say)
    with h5py.File(four, "w") as handle:
        handle["numbers"] = np.arange(4)
    capsys.readouterr()
    decoded = tmp_path / "r.binary"
    assert main(["decompress", str(out), "-o", str(decoded), "--reference", str(four)]) == 1
    error = capsys.readouterr().err
    assert "HDF5 file" in error and "not a MERL" in error and "header gives dimensions" not in error
    assert not decoded.exists()


# --- NBRDF fits read directly -----------------------------------------------------------------------------------


@pytest.fixture
def fit_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "unzipped" / "merl-nbrdf"
    write_fit_files(folder, "grey", constant_fit((0.05, 0.06, 0.07)))
    write_fit_files(folder, "lobe", lobe_fit(3))
    (folder / "LICENSE").write_text("MIT")
    return folder


def test_compress_reads_one_fit_with_its_provenance(tmp_path: Path, fit_folder: Path, tiny_model: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "grey.bvae"
    assert _compress([fit_folder / "grey.h5"], out, tiny_model, "--provenance") == 0
    assert "grey" in capsys.readouterr().out
    records = read_bvae(out).records
    assert [r.name for r in records] == ["grey"]
    assert records[0].meta["source_kind"] == "nbrdf-proxy"
    assert records[0].meta["source_sha256"] == hashlib.sha256((fit_folder / "grey.h5").read_bytes()).hexdigest()
    assert np.isfinite(records[0].meta["relae"]["mapped"])


@pytest.mark.slow
def test_compress_reads_the_zip_the_folder_and_the_description(tmp_path: Path, fit_folder: Path,
                                                               tiny_model: Path) -> None:
    archive = write_fit_archive(tmp_path / "fits.zip", {"grey": constant_fit((0.05, 0.06, 0.07)),
                                                         "lobe": lobe_fit(3)})
    names = {}
    for label, inputs in (("zip", [archive]), ("folder", [fit_folder]),
                          ("json", [fit_folder / "grey.json", fit_folder / "lobe.json"])):
        out = tmp_path / f"{label}.bvae"
        assert _compress(inputs, out, tiny_model, "--no-measure", "--provenance") == 0, label
        records = read_bvae(out).records
        names[label] = [r.name for r in records]
        assert {r.meta["source_kind"] for r in records} == {"nbrdf-proxy"}, label
    assert names == {"zip": ["grey", "lobe"], "folder": ["grey", "lobe"], "json": ["grey", "lobe"]}
    # the same fits, read three ways, give the same codes
    codes = {label: np.stack([r.mu for r in read_bvae(tmp_path / f"{label}.bvae").records]) for label in names}
    np.testing.assert_array_equal(codes["zip"], codes["folder"])
    np.testing.assert_array_equal(codes["json"], codes["folder"])


@pytest.mark.slow
def test_compress_folder_mixes_measured_files_and_fits(tmp_path: Path, fit_folder: Path, red_plastic_file: Path,
                                                       tiny_model: Path) -> None:
    (fit_folder / "red-plastic.binary").symlink_to(red_plastic_file)
    out = tmp_path / "mixed.bvae"
    assert _compress([fit_folder], out, tiny_model, "--no-measure") == 0
    assert [r.name for r in read_bvae(out).records] == ["grey", "lobe", "red-plastic"]


def test_compress_says_what_is_missing(tmp_path: Path, fit_folder: Path, tiny_model: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x.bvae"
    # the folder the archive was unpacked into: the fits are one level down
    assert _compress([fit_folder.parent], out, tiny_model) == 1
    error = capsys.readouterr().err
    assert "NBRDF fit" in error and "subfolder merl-nbrdf" in error
    # a description without its weights
    lonely = tmp_path / "lonely.json"
    lonely.write_text(keras_description())
    assert _compress([lonely], out, tiny_model) == 1
    assert "lonely.h5 is missing" in capsys.readouterr().err
    # a description of another network
    write_fit_files(tmp_path / "odd", "odd", constant_fit((0.1, 0.1, 0.1)),
                    description=keras_description(("tanh", "relu", "linear")))
    assert _compress([tmp_path / "odd" / "odd.h5"], out, tiny_model) == 1
    assert "not the NBRDF network" in capsys.readouterr().err
    # an archive of something else
    other = tmp_path / "other.zip"
    with zipfile.ZipFile(other, "w") as handle:
        handle.writestr("notes.txt", "hello")
    assert _compress([other], out, tiny_model) == 1
    assert "no NBRDF weight files" in capsys.readouterr().err
    assert not out.exists()


def test_dataset_build_takes_the_unzipped_folder(tmp_path: Path, fit_folder: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    from brdfcodec.datasets.hdf5 import BrdfDataset

    out = tmp_path / "d.h5"
    assert main(["dataset", "build", "--nbrdf-zip", str(fit_folder), "--materials", "lobe", "--no-tables",
                 "--quiet", "-o", str(out)]) == 0
    with BrdfDataset(out) as dataset:
        assert dataset.names == ["lobe"] and dataset.source_kind == "nbrdf-proxy"
    capsys.readouterr()
    assert main(["dataset", "build", "--nbrdf-zip", str(fit_folder.parent), "--quiet", "-o",
                 str(tmp_path / "e.h5")]) == 1
    error = capsys.readouterr().err
    assert "Is a directory" not in error and "subfolder merl-nbrdf" in error


@pytest.mark.slow
def test_decompress_reference_takes_a_fit_or_its_archive(tmp_path: Path, fit_folder: Path, tiny_model: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "lobe.bvae"
    assert _compress([fit_folder / "lobe.h5"], out, tiny_model) == 0
    stored = json.loads(json.dumps(read_bvae(out).records[0].meta.get("relae", {})))
    archive = write_fit_archive(tmp_path / "fits.zip", {"grey": constant_fit((0.05, 0.06, 0.07)),
                                                         "lobe": lobe_fit(3)})
    capsys.readouterr()
    lines = []
    for reference in (fit_folder / "lobe.h5", archive, fit_folder):
        decoded = tmp_path / f"{reference.name}.binary"
        assert main(["decompress", str(out), "-o", str(decoded), "--reference", str(reference)]) == 0
        lines.append([line for line in capsys.readouterr().out.splitlines() if line.startswith("RelAE against")][0])
    values = {line.split(": ", 1)[1] for line in lines}
    assert len(values) == 1  # the same material, however it is named
    assert stored == {} or f"{stored['mapped']:.4f}" in values.pop()
    # an archive without the material
    other = write_fit_archive(tmp_path / "other.zip", {"a": lobe_fit(1), "b": lobe_fit(2)})
    assert main(["decompress", str(out), "-o", str(tmp_path / "x.binary"), "--reference", str(other)]) == 2
    assert "none named 'lobe'" in capsys.readouterr().err


@pytest.mark.shared
def test_compress_reads_a_published_fit_with_the_shipped_model(tmp_path: Path, nbrdf_zip: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "merl-nbrdf"
    folder.mkdir()
    with zipfile.ZipFile(nbrdf_zip) as archive:
        for suffix in (".h5", ".json"):
            member = f"merl-nbrdf/gold-metallic-paint{suffix}"
            (folder / Path(member).name).write_bytes(archive.read(member))
    out = tmp_path / "g.bvae"
    assert main(["compress", str(folder / "gold-metallic-paint.h5"), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "gold-metallic-paint" in printed and "RelAE mapped" in printed
    assert [r.name for r in read_bvae(out).records] == ["gold-metallic-paint"]


def test_fit_reader_checks_the_description_in_an_archive(tmp_path: Path) -> None:
    from brdfcodec.datasets.nbrdf import iter_nbrdf_zip

    archive = tmp_path / "odd.zip"
    with zipfile.ZipFile(archive, "w") as handle:
        source = tmp_path / "src"
        write_fit_files(source, "odd", constant_fit((0.1, 0.1, 0.1)), description=json.dumps({"config": 3}))
        handle.write(source / "odd.h5", "merl-nbrdf/odd.h5")
        handle.write(source / "odd.json", "merl-nbrdf/odd.json")
    with pytest.raises(SourceFormatError, match="odd.json.*not a Keras model description"):
        next(iter_nbrdf_zip(archive))


# --- output types, checked alike -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["analytic", "gold", "-o", "g.bvae"], ".binary"),
        (["analytic", "gold", "-o", "g"], ".binary"),
        (["compress", "in.binary", "-o", "x.binary"], ".bvae"),
        (["extract", "in.bvae", "--material", "a", "-o", "x.binary"], ".bvae"),
        (["edit", "traverse", "in.bvae", "--material", "a", "--dim", "1", "-o", "x.binary"], ".bvae"),
        (["dataset", "build", "--analytic", "-o", "x.bvae"], ".h5"),
        (["render", "in.bvae", "-o", "x.jpg"], "one of .png, .exr"),
    ],
)
def test_every_command_refuses_another_output_type(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str], argv: list[str],
                                                   expected: str) -> None:
    monkeypatch.chdir(tmp_path)  # the inputs do not exist: the output type is checked first
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert f"the output name must end in {expected}" in error and f"bvae {argv[0]}" in error
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def two_material_library(tmp_path: Path, fit_folder: Path, tiny_model: Path) -> Path:
    library = tmp_path / "lib.bvae"
    assert _compress([fit_folder], library, tiny_model, "--no-measure") == 0
    return library


@pytest.mark.slow
def test_decompress_writes_a_folder_only_when_asked(tmp_path: Path, two_material_library: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    lib = str(two_material_library)
    work = tmp_path / "work"
    work.mkdir()
    # a file name for two materials: refused, nothing made
    assert main(["decompress", lib, "-o", str(work / "x.binary")]) == 2
    error = capsys.readouterr().err
    assert "2 materials" in error and "--material" in error and f"-o {work / 'x'}/" in error
    assert list(work.iterdir()) == []
    # --format is for folders
    assert main(["decompress", lib, "--material", "grey", "-o", str(work / "g.binary"), "--format", "npy"]) == 2
    # a usage error after a folder was asked for leaves no folder behind
    assert main(["decompress", lib, "-o", str(work / "bad") + "/", "--phi-d", "0"]) == 2
    assert list(work.iterdir()) == []
    capsys.readouterr()
    # the ways to ask for a folder: a trailing slash, --output-dir, no extension (as before)
    for argv, folder in ((["-o", str(work / "slash") + "/"], "slash"), (["--output-dir", str(work / "dir.d")], "dir.d"),
                         (["-o", str(work / "plain"), "--format", "npy"], "plain")):
        assert main(["decompress", lib, *argv]) == 0, argv
        suffix = ".npy" if "npy" in argv else ".binary"
        assert sorted(p.name for p in (work / folder).iterdir()) == [f"grey{suffix}", f"lobe{suffix}"]
    # one material: a file, or a folder when asked
    assert main(["decompress", lib, "--material", "lobe", "-o", str(work / "lobe.binary")]) == 0
    assert (work / "lobe.binary").is_file()
    assert main(["decompress", lib, "--material", "lobe", "-o", str(work / "one") + "/"]) == 0
    assert [p.name for p in (work / "one").iterdir()] == ["lobe.binary"]
    # -o and --output-dir are one choice
    assert main(["decompress", lib, "-o", str(work / "a") + "/", "--output-dir", str(work / "b")]) == 2
    assert "not allowed with" in capsys.readouterr().err


def test_compress_summary_says_when_no_record_has_a_latent(tmp_path: Path, red_plastic_file: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "small.bvae"  # below every record with a latent: one without it
    assert main(["compress", str(red_plastic_file), "-o", str(out), "--bytes", "10", "--effort", "0",
                 "--latent", "auto"]) == 0
    summary = capsys.readouterr().out.strip().splitlines()[-1]
    assert summary.startswith(f"wrote {out}") and "no latent (basis-only records" in summary
    assert "latents float" not in summary
    assert main(["compress", str(red_plastic_file), "-o", str(tmp_path / "full.bvae"), "--effort", "0"]) == 0
    assert "latents float32;" in capsys.readouterr().out.strip().splitlines()[-1]
