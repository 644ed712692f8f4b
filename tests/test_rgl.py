"""RGL .bsdf input: header inspection, tabulation with Mitsuba's measured plugin, refusals, CLI round trip."""

from __future__ import annotations

import shutil
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.cli import main
from brdfcodec.conventions import MERL_COLOR_SCALE, UNMEASURED_VALUE
from brdfcodec.errors import OptionalDependencyError, SourceFormatError
from brdfcodec.io.inputs import read_measured
from brdfcodec.io.merl import read_merl
from brdfcodec.io.rgl import (
    RGL_SOURCE_KIND,
    RglField,
    RglHeader,
    check_supported,
    is_rgl_file,
    read_rgl_bsdf,
    read_rgl_header,
)
from brdfcodec.representation.coords import (
    directions_from_half_diff,
    phi_d_from_index,
    theta_d_from_index,
    theta_h_from_index,
)
from brdfcodec.representation.mask import horizon_mask

PAPER_WHITE_SHA256 = "9d641fbb56358275509b2b1053d1002313e2dabc7b3ec202eb5c5a6943f7b70e"


@pytest.fixture(scope="module")
def rgl_file(shared_dir: Path) -> Path:
    path = shared_dir / "data" / "rgl" / "paper_white_rgb.bsdf"
    if not path.is_file():
        pytest.skip(f"real RGL measurement not found at {path}")
    return path


@pytest.fixture(scope="module")
def mitsuba_llvm() -> None:
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (extra brdfcodec[rgl])")
    from brdfcodec.runtime.mitsuba import LibLLVMNotFoundError, find_libllvm

    try:
        find_libllvm()
    except LibLLVMNotFoundError as error:
        pytest.skip(f"{error} (the scalar fallback takes minutes)")


@pytest.fixture(scope="module")
def paper_white(rgl_file: Path, mitsuba_llvm: None) -> object:
    return read_rgl_bsdf(rgl_file)


def _field_shape_position(data: bytes, name: bytes) -> int:
    """Byte position of the first shape entry of a field in a tensor-file header."""
    start = data.index(struct.pack("<H", len(name)) + name) + 2 + len(name)
    return start + 2 + 1 + 8  # ndim (u16), dtype (u8), offset (u64)


@pytest.mark.shared
def test_header_of_the_real_file(rgl_file: Path) -> None:
    header = read_rgl_header(rgl_file)
    assert is_rgl_file(rgl_file)
    assert header.description == "White A4 paper (160 gsm)"
    assert header.isotropic and header.colour == "rgb"
    assert header.theta_i_count == 8
    assert header.fields["rgb"].shape == (1, 8, 3, 32, 32)
    check_supported(header)  # does not raise


@pytest.mark.shared
def test_tabulation_matches_mitsubas_eval(paper_white: object, rgl_file: Path) -> None:
    brdf = paper_white
    assert brdf.name == "paper_white"
    assert brdf.source_kind == RGL_SOURCE_KIND and brdf.source_sha256 == PAPER_WHITE_SHA256
    below = ~horizon_mask()
    assert np.all(brdf.values[:, below] == UNMEASURED_VALUE)
    assert np.all(brdf.values[:, ~below] >= 0.0)
    assert brdf.valid_fraction > 0.7
    # Independent check: Mitsuba's scalar variant at the bins' representative directions.
    import mitsuba as mi

    previous = mi.variant()
    mi.set_variant("scalar_rgb")
    try:
        bsdf = mi.load_dict({"type": "measured", "filename": str(rgl_file)})
        si = mi.SurfaceInteraction3f()
        si.sh_frame = mi.Frame3f(mi.Normal3f(0.0, 0.0, 1.0))
        above = horizon_mask()
        checked = 0
        for th, td, pd in [(0, 10, 90), (5, 30, 0), (30, 45, 120), (60, 20, 179), (40, 10, 90), (80, 70, 45)]:
            if not above[th, td, pd]:
                assert np.all(brdf.values[:, th, td, pd] == UNMEASURED_VALUE)
                continue
            checked += 1
            wi, wo = directions_from_half_diff(theta_h_from_index(th), theta_d_from_index(td), phi_d_from_index(pd))
            si.wi = mi.Vector3f(*wi)
            value = np.asarray(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*wo)), dtype=np.float64)
            expected = value / wo[2] / MERL_COLOR_SCALE
            np.testing.assert_allclose(brdf.values[:, th, td, pd], expected, rtol=2e-4, atol=1e-6)
        assert checked >= 5
    finally:
        if previous:
            mi.set_variant(previous)


@pytest.mark.shared
@pytest.mark.slow
def test_compress_and_decompress_round_trip(rgl_file: Path, mitsuba_llvm: None, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    bvae = tmp_path / "p.bvae"
    assert main(["compress", str(rgl_file), "-o", str(bvae), "--provenance"]) == 0  # source kind and hash stored
    assert "paper_white" in capsys.readouterr().out
    from brdfcodec.format.bvae import read_bvae

    record = read_bvae(bvae).records[0]
    assert record.name == "paper_white"
    assert record.meta["source_kind"] == RGL_SOURCE_KIND
    assert record.meta["source_sha256"] == PAPER_WHITE_SHA256
    assert 0.0 < record.meta["relae"]["mapped"] < 0.5
    out = tmp_path / "p.binary"
    assert main(["decompress", str(bvae), "-o", str(out), "--reference", str(rgl_file)]) == 0
    assert "RelAE" in capsys.readouterr().out
    decoded = read_merl(out)
    assert decoded.values.shape == (3, 90, 90, 180) and np.isfinite(decoded.values).all()
    # Rendering takes the RGL file too, as the reference of --compare and as the material itself.
    capsys.readouterr()
    image = tmp_path / "p.png"
    assert main(["render", str(bvae), "-o", str(image), "--size", "32", "--compare", str(rgl_file)]) == 0
    assert "ΔE ITP" in capsys.readouterr().out and image.stat().st_size > 0
    assert main(["render", str(rgl_file), "-o", str(tmp_path / "q.png"), "--size", "32"]) == 0


@pytest.mark.shared
def test_info_describes_rgl_files_without_mitsuba(rgl_file: Path, capsys: pytest.CaptureFixture[str],
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # importing it now fails
    assert main(["info", str(rgl_file)]) == 0
    out = capsys.readouterr().out
    assert "RGL .bsdf measurement" in out and "White A4 paper" in out and PAPER_WHITE_SHA256 in out


@pytest.mark.shared
def test_missing_mitsuba_is_a_clear_error(rgl_file: Path, monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "mitsuba", None)
    with pytest.raises(OptionalDependencyError, match=r"brdfcodec\[rgl\]"):
        read_measured(rgl_file)
    assert main(["compress", str(rgl_file), "-o", str(tmp_path / "x.bvae")]) == 1
    assert "brdfcodec[rgl]" in capsys.readouterr().err
    assert not (tmp_path / "x.bvae").exists()


@pytest.mark.shared
def test_anisotropic_file_is_refused(rgl_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = bytearray(rgl_file.read_bytes())
    position = _field_shape_position(bytes(data), b"phi_i")
    assert struct.unpack_from("<Q", data, position)[0] == 1
    struct.pack_into("<Q", data, position, 2)  # two incident azimuths: an anisotropic layout
    bad = tmp_path / "aniso_rgb.bsdf"
    bad.write_bytes(bytes(data))
    assert not read_rgl_header(bad).isotropic
    with pytest.raises(SourceFormatError, match="anisotropic"):
        read_rgl_bsdf(bad)
    assert main(["compress", str(bad), "-o", str(tmp_path / "a.bvae")]) == 1
    err = capsys.readouterr().err
    assert str(bad) in err and "anisotropic" in err
    assert main(["info", str(bad)]) == 0
    assert "anisotropic" in capsys.readouterr().out


def test_spectral_and_colourless_files_are_refused(tmp_path: Path) -> None:
    base = {name: RglField("<f4", 0, (1,)) for name in ("theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance")}
    spectral = RglHeader(tmp_path / "s.bsdf", (1, 0), {**base, "spectra": RglField("<f4", 0, (1,))}, "")
    with pytest.raises(SourceFormatError, match="spectral"):
        check_supported(spectral)
    with pytest.raises(SourceFormatError, match="no RGB"):
        check_supported(RglHeader(tmp_path / "n.bsdf", (1, 0), base, ""))


@pytest.mark.shared
def test_broken_rgl_files_name_the_file(rgl_file: Path, tmp_path: Path) -> None:
    truncated = tmp_path / "truncated.bsdf"
    truncated.write_bytes(rgl_file.read_bytes()[:100_000])
    with pytest.raises(SourceFormatError, match="past the end"):
        read_rgl_header(truncated)
    header_only = tmp_path / "header.bsdf"
    header_only.write_bytes(rgl_file.read_bytes()[:40])
    with pytest.raises(SourceFormatError, match="truncated"):
        read_rgl_header(header_only)
    not_rgl = tmp_path / "other.bsdf"
    not_rgl.write_bytes(b"\x00" * 64)
    with pytest.raises(SourceFormatError, match="not an RGL"):
        read_rgl_header(not_rgl)
    assert not is_rgl_file(not_rgl)
    folder = tmp_path / "folder.bsdf"
    folder.mkdir()
    with pytest.raises(IsADirectoryError):
        read_rgl_header(folder)


def test_merl_files_still_read_through_read_measured(red_plastic_file: Path) -> None:
    brdf = read_measured(red_plastic_file)
    assert brdf.name == "red-plastic" and brdf.source_kind is None
    np.testing.assert_array_equal(brdf.values, read_merl(red_plastic_file).values)


@pytest.mark.shared
def test_renamed_rgl_file_is_told_by_content(rgl_file: Path, tmp_path: Path, mitsuba_llvm: None) -> None:
    renamed = tmp_path / "paper.binary"
    shutil.copyfile(rgl_file, renamed)
    brdf = read_measured(renamed)
    assert brdf.source_kind == RGL_SOURCE_KIND and brdf.name == "paper"
