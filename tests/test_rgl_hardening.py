"""RGL ``.bsdf`` reader, third hardening pass (issue 49, R3-08 and R3-21): what ``bvae info`` accepts,
``bvae compress`` reads.

Every crafted file is built here from the small synthetic tensor file of :mod:`tensor_files` (no shared data,
no Mitsuba needed); one test repeats the red-team construction on ``paper_white_rgb.bsdf`` when the shared data
is present, and one checks with Mitsuba (when installed) that files at the accepted limits evaluate finite.
"""

from __future__ import annotations

import struct
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from tensor_files import field_shape_position, small_rgl_fields, tensor_file

from brdfcodec.cli import main
from brdfcodec.errors import SourceFormatError
from brdfcodec.io import rgl
from brdfcodec.io.rgl import (
    MAX_FIELD_VALUE,
    MIN_ANGLE_STEP,
    MIN_SIGMA,
    NegativeColourWarning,
    check_supported,
    read_rgl_header,
)

Fields = dict[str, np.ndarray]


def _write(tmp_path: Path, fields: Fields, name: str = "crafted_rgb.bsdf") -> Path:
    path = tmp_path / name
    path.write_bytes(tensor_file(fields))
    return path


def _set(name: str, value: float, where: tuple[object, ...] = (Ellipsis,)) -> Callable[[Fields], None]:
    def change(fields: Fields) -> None:
        fields[name][where] = value
    return change


def _theta(values: np.ndarray) -> Callable[[Fields], None]:
    def change(fields: Fields) -> None:
        fields["theta_i"] = values.astype("<f4")
    return change


# Each: a change of a valid file, the field the message must name, and a phrase of the message.
_REFUSED = {
    "ndf 3e38 (overflows the plugin's products)": (_set("ndf", 3e38), "'ndf'", "beyond"),
    "ndf just above the bound": (_set("ndf", MAX_FIELD_VALUE * 1.01, (0, 3)), "'ndf'", "beyond"),
    "sigma zero (the divisor)": (_set("sigma", 0.0), "'sigma'", "divides"),
    "sigma one zero entry": (_set("sigma", 0.0, (1, 5)), "'sigma'", "divides"),
    "sigma denormal": (_set("sigma", 1e-40, (0, 0)), "'sigma'", "below"),
    "vndf zero": (_set("vndf", 0.0), "'vndf'", "no positive density"),
    "vndf one zero slice (a 2 x 2 crop's corner)": (_set("vndf", 0.0, (0, 2)), "'vndf'", "θi 2"),
    "vndf denormal slice": (_set("vndf", 1e-44, (0, 1)), "'vndf'", "no positive density"),
    "vndf negative": (_set("vndf", -1.0, (0, 0, 3, 3)), "'vndf'", "negative"),
    "luminance 1e20": (_set("luminance", 1e20, (0, 1, 2, 2)), "'luminance'", "beyond"),
    "rgb 1e11": (_set("rgb", 1e11, (0, 0, 1, 1, 1)), "'rgb'", "beyond"),
    "rgb -1e11": (_set("rgb", -1e11, (0, 0, 1, 1, 1)), "'rgb'", "beyond"),
    "rgb all negative": (_set("rgb", -1.0), "'rgb'", "no positive value"),
    "theta_i steps that underflow": (_theta(np.linspace(0.0, 1e-37, 3)), "'theta_i'", "step"),
    "theta_i steps below the minimum": (_theta(np.array([0.0, MIN_ANGLE_STEP / 2, 1.0])), "'theta_i'", "step"),
    "theta_i beyond pi/2": (_theta(np.array([0.0, 1.0, 2.0])), "'theta_i'", "outside"),
    "theta_i negative": (_theta(np.array([-0.5, 0.5, 1.0])), "'theta_i'", "outside"),
}


@pytest.mark.parametrize("case", list(_REFUSED))
@pytest.mark.slow
def test_crafted_fields_are_refused_by_info_and_compress_alike(case: str, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """R3-08: the files ``bvae info`` called readable and ``bvae compress`` refused after Mitsuba returned
    non-finite values are refused by the header checks, with the same message from both commands."""
    change, field, phrase = _REFUSED[case]
    fields = small_rgl_fields()
    change(fields)
    path = _write(tmp_path, fields)
    with pytest.raises(SourceFormatError) as caught:
        check_supported(read_rgl_header(path))
    message = str(caught.value)
    assert str(path) in message and field in message and phrase in message
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "brdfcodec reads no" in out and caught.value.problem in out
    output = tmp_path / "x.bvae"
    assert main(["compress", str(path), "-o", str(output)]) == 1
    err = capsys.readouterr().err
    assert caught.value.problem in err and "Traceback" not in err
    assert not output.exists()


def test_values_at_the_limits_are_accepted(tmp_path: Path) -> None:
    """The bounds are not off by one: σ at its minimum, densities and colours at their maximum, the smallest
    angle step, θi ending at float32's π/2."""
    fields = small_rgl_fields()
    fields["sigma"][0, 0] = MIN_SIGMA
    fields["ndf"][1, 1] = MAX_FIELD_VALUE
    fields["rgb"][0, 0, 0, 0, 0] = MAX_FIELD_VALUE
    fields["vndf"][0, 1] = 0.0
    fields["vndf"][0, 1, 0, 0] = rgl.MIN_VNDF_PEAK
    fields["theta_i"] = np.array([0.0, 2 * MIN_ANGLE_STEP, np.pi / 2], dtype="<f4")
    check_supported(read_rgl_header(_write(tmp_path, fields)))


def test_limits_evaluate_finite_in_mitsuba(tmp_path: Path) -> None:
    """What the checks accept at their limits, Mitsuba's plugin evaluates to finite values (float32 products
    of the largest densities and colours over the smallest σ)."""
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (extra brdfcodec[rgl])")
    fields = small_rgl_fields()
    fields["sigma"][:] = MIN_SIGMA
    fields["ndf"][:] = MAX_FIELD_VALUE
    fields["rgb"][:] = MAX_FIELD_VALUE
    fields["luminance"][:] = MAX_FIELD_VALUE
    fields["vndf"][:] = rgl.MIN_VNDF_PEAK
    path = _write(tmp_path, fields)
    check_supported(read_rgl_header(path))
    previous = mi.variant()
    mi.set_variant("scalar_rgb")
    try:
        bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
        si = mi.SurfaceInteraction3f()
        si.sh_frame = mi.Frame3f(mi.Normal3f(0.0, 0.0, 1.0))
        values = []
        for theta_i in (0.0, 0.4, 1.2, 1.5):
            si.wi = mi.Vector3f(np.sin(theta_i), 0.0, np.cos(theta_i))
            for theta_o, phi_o in ((0.0, 0.0), (0.4, 3.1), (1.2, 1.0), (1.55, 2.0)):
                wo = mi.Vector3f(np.sin(theta_o) * np.cos(phi_o), np.sin(theta_o) * np.sin(phi_o), np.cos(theta_o))
                values.append(np.asarray(bsdf.eval(mi.BSDFContext(), si, wo), dtype=np.float64))
    finally:
        if previous is not None:
            mi.set_variant(previous)
    assert np.isfinite(values).all() and np.max(values) > 0


def test_negative_colours_are_counted_in_a_warning(tmp_path: Path) -> None:
    """R3-21: negative colours (clipped to 0 in the MERL table) are no longer dropped silently."""
    fields = small_rgl_fields()
    fields["rgb"][0, 1, 2, :2, :] = -0.25  # 2 rows of 4
    path = _write(tmp_path, fields)
    with pytest.warns(NegativeColourWarning) as record:
        check_supported(read_rgl_header(path))
    message = str(record[0].message)
    assert str(path) in message and "8 negative values of 144" in message and "-0.25" in message
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a file without negative colours warns nothing
        check_supported(read_rgl_header(_write(tmp_path, small_rgl_fields(), "clean_rgb.bsdf")))


def test_cli_prints_the_negative_colour_warning(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fields = small_rgl_fields()
    fields["rgb"][0, 0, 0, 0, 0] = -1.0
    path = _write(tmp_path, fields)
    assert main(["info", str(path)]) == 0
    captured = capsys.readouterr()
    assert "reads yes" in captured.out
    assert "warning" in captured.err and "1 negative values" in captured.err


def _patch_offset(data: bytes, field: bytes, offset: int) -> bytes:
    out = bytearray(data)
    struct.pack_into("<Q", out, field_shape_position(data, field) - 8, offset)
    return bytes(out)


def _offset(data: bytes, field: bytes) -> int:
    return int(struct.unpack_from("<Q", data, field_shape_position(data, field) - 8)[0])


def test_field_inside_the_header_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """R3-21: a field whose bytes start inside the header (the red-team file: rgb at offset 0) was read as data."""
    data = tensor_file(small_rgl_fields())
    path = tmp_path / "offset0_rgb.bsdf"
    for offset in (0, 12, _offset(data, b"version") - 1):
        path.write_bytes(_patch_offset(data, b"rgb", offset))
        with pytest.raises(SourceFormatError, match="'rgb' starts at byte .*inside the header"):
            read_rgl_header(path)
    assert main(["info", str(path)]) == 1
    assert str(path) in capsys.readouterr().err
    assert main(["compress", str(path), "-o", str(tmp_path / "x.bvae")]) == 1


def test_overlapping_fields_are_refused(tmp_path: Path) -> None:
    data = tensor_file(small_rgl_fields())
    path = tmp_path / "overlap_rgb.bsdf"
    path.write_bytes(_patch_offset(data, b"ndf", _offset(data, b"sigma") + 4))  # ndf read from sigma's bytes
    with pytest.raises(SourceFormatError, match="'sigma' and 'ndf' overlap") as caught:
        read_rgl_header(path)
    assert str(path) in str(caught.value)
    path.write_bytes(_patch_offset(data, b"ndf", _offset(data, b"sigma")))  # the same bytes exactly
    with pytest.raises(SourceFormatError, match="overlap"):
        read_rgl_header(path)
    path.write_bytes(data)
    read_rgl_header(path)  # the untouched layout is fine


def test_fields_are_checked_a_chunk_at_a_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Memory stays bounded on a large file: fields are read in chunks, and a bad value in any chunk (the
    last one, of a size that does not divide the field) is still found."""
    monkeypatch.setattr(rgl, "_CHUNK_VALUES", 7)
    fields = small_rgl_fields()
    path = _write(tmp_path, fields)
    check_supported(read_rgl_header(path))
    fields["rgb"].reshape(-1)[-1] = np.inf
    with pytest.raises(SourceFormatError, match="'rgb' holds non-finite"):
        check_supported(read_rgl_header(_write(tmp_path, fields, "last_rgb.bsdf")))
    fields = small_rgl_fields()
    fields["luminance"].reshape(-1)[8] = -1.0
    with pytest.raises(SourceFormatError, match="'luminance' holds negative"):
        check_supported(read_rgl_header(_write(tmp_path, fields, "second_rgb.bsdf")))


@pytest.mark.shared
@pytest.mark.slow
def test_red_team_construction_on_the_real_file(shared_dir: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """``make_bsdf.py``'s R3-08 files, rebuilt from ``paper_white_rgb.bsdf``: each refused by info and compress."""
    source = shared_dir / "data" / "rgl" / "paper_white_rgb.bsdf"
    if not source.is_file():
        pytest.skip(f"real RGL measurement not found at {source}")
    header = read_rgl_header(source)
    check_supported(header)
    with open(source, "rb") as stream:
        fields: Fields = {}
        for name, field in sorted(header.fields.items(), key=lambda item: item[1].offset):
            stream.seek(field.offset)
            fields[name] = np.frombuffer(stream.read(field.nbytes), dtype=field.dtype).reshape(field.shape).copy()
    crops = dict(fields)
    crops.update(vndf=fields["vndf"][:, :, :2, :2].copy(), luminance=fields["luminance"][:, :, :2, :2].copy(),
                 rgb=fields["rgb"][:, :, :, :2, :2].copy(), ndf=fields["ndf"][:, :2].copy(),
                 sigma=fields["sigma"][:, :2].copy())
    crafted = {"grids_2x2": crops}
    for label, name, value in (("ndf_3e38", "ndf", 3e38), ("sigma_zero", "sigma", 0.0), ("vndf_zero", "vndf", 0.0)):
        changed = dict(fields)
        changed[name] = np.full_like(fields[name], value)
        crafted[label] = changed
    tiny = dict(fields)
    tiny["theta_i"] = np.linspace(0, 1e-37, fields["theta_i"].size).astype("<f4")
    crafted["theta_i_tiny_steps"] = tiny
    for label, changed in crafted.items():
        path = _write(tmp_path, changed, f"bsdf_{label}.bsdf")
        assert main(["info", str(path)]) == 0
        assert "brdfcodec reads no" in capsys.readouterr().out, label
        assert main(["compress", str(path), "-o", str(tmp_path / "x.bvae")]) == 1, label
        assert str(path) in capsys.readouterr().err


# --------------------------------------------------------------------------- the writer (R3-09)


def test_writer_resolution_is_bounded_by_the_file_size() -> None:
    """Each size within its range, together beyond the largest file: a ValueError naming the size, before any
    work (the red-team's 512/512/2048 asked for a 16 GiB float64 array)."""
    from brdfcodec.io.rgl_writer import MAX_FILE_BYTES, RglResolution

    largest = RglResolution(theta_i=32, ndf=2048, vndf=2048, luminance=32)  # the red-team's --bsdf-vndf 2048
    assert largest.nbytes <= MAX_FILE_BYTES
    for sizes in ({"theta_i": 512, "ndf": 2048, "vndf": 2048, "luminance": 512},
                  {"theta_i": 65, "ndf": 2048, "vndf": 2048}, {"theta_i": 512, "luminance": 512}):
        with pytest.raises(ValueError, match="GiB"):
            RglResolution(**sizes)  # type: ignore[arg-type]


def test_written_file_size_is_what_the_resolution_says(tmp_path: Path, analytic_tables: dict) -> None:
    from brdfcodec.io.rgl_writer import RglResolution, write_rgl_bsdf

    resolution = RglResolution(theta_i=5, ndf=33, vndf=37, luminance=7)
    path = write_rgl_bsdf(tmp_path / "r.bsdf", analytic_tables["red-plastic"].values, name="r",
                          resolution=resolution, description="")  # empty: the default one
    header = read_rgl_header(path)
    tables = sum(field.nbytes for name, field in header.fields.items() if name not in ("version", "description"))
    assert tables == resolution.nbytes
    check_supported(header)  # the writer's files pass the reader's checks


def test_writer_output_does_not_depend_on_the_chunk_size(tmp_path: Path, analytic_tables: dict,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """The writer works a θi slice at a time and its lookups and warps in chunks: the bytes are those of one
    pass over everything (chunks of 97 points against the default)."""
    from brdfcodec.io import rgl_writer

    resolution = rgl_writer.RglResolution(theta_i=4, ndf=40, vndf=48, luminance=12)
    table = analytic_tables["gold"].values
    whole = rgl_writer.write_rgl_bsdf(tmp_path / "whole.bsdf", table, name="g", resolution=resolution)
    monkeypatch.setattr(rgl_writer, "_CHUNK", 97)
    chunked = rgl_writer.write_rgl_bsdf(tmp_path / "chunked.bsdf", table, name="g", resolution=resolution)
    assert whole.read_bytes() == chunked.read_bytes()
    reflectance, valid = rgl_writer._checked_reflectance(whole, table, "g")
    fields = rgl_writer.rgl_fields(reflectance, valid, resolution=resolution, description="g (brdfcodec export)")
    assert rgl_writer.tensor_file_bytes(fields) == whole.read_bytes()  # the in-memory API writes the same file


@pytest.mark.slow
def test_writer_memory_does_not_grow_with_the_elevations(tmp_path: Path, analytic_tables: dict) -> None:
    """Memory is a θi slice's worth, not the file's: peak traced memory for 24 elevations stays within a few MB
    of that for 3 (before: two float64 V × V tables per elevation and two copies of the file's bytes)."""
    import tracemalloc

    from brdfcodec.io.rgl_writer import RglResolution, write_rgl_bsdf

    table = analytic_tables["white-matte"].values
    peaks = []
    for theta_i in (3, 24):
        resolution = RglResolution(theta_i=theta_i, ndf=64, vndf=384, luminance=8)
        tracemalloc.start()
        write_rgl_bsdf(tmp_path / f"t{theta_i}.bsdf", table, name="w", resolution=resolution)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    growth = peaks[1] - peaks[0]
    per_elevation = 384 * 384 * 8  # one float64 VNDF table (before: 21 more elevations grew the peak by 20 MB)
    assert growth < 4 * per_elevation, (peaks, growth)


@pytest.mark.slow
def test_decompress_refuses_a_resolution_beyond_the_largest_file(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """R3-09: the red-team's settings end in a usage error (exit 2), not MemoryError (exit 3); nothing written."""
    from brdfcodec.codec import MaterialLibrary
    from brdfcodec.examples import example_library

    with MaterialLibrary(example_library()) as library:
        name = library.names[0]
    target = tmp_path / "x.bsdf"
    code = main(["decompress", str(example_library()), "--material", name, "-o", str(target), "--bsdf-theta-i",
                 "512", "--bsdf-grid", "512", "--bsdf-vndf", "2048"])
    assert code == 2
    err = capsys.readouterr().err
    assert "GiB" in err and "--bsdf-vndf" in err and "internal error" not in err
    assert not target.exists() and list(tmp_path.iterdir()) == []
