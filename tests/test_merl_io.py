"""MERL .binary reading and writing: exactness, an independent reader, and every kind of bad input."""

from __future__ import annotations

import hashlib
import os
import re
import struct
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.conventions import TABLE_SHAPE, UNMEASURED_VALUE
from brdfcodec.errors import MerlFormatError, NonFiniteValueError
from brdfcodec.io.genuine import genuine_merl_checksums, genuine_merl_name
from brdfcodec.io.merl import MERL_FILE_SIZE, MerlBRDF, read_merl, write_merl
from brdfcodec.representation.mask import horizon_mask

N = 90 * 90 * 180


def independent_read(path: Path) -> np.ndarray:
    """A reader written from the spec alone: struct for the header, numpy for the blocks."""
    data = path.read_bytes()
    dims = struct.unpack("<3i", data[:12])
    assert dims == (90, 90, 180)
    assert len(data) == 12 + 3 * 8 * N
    flat = np.frombuffer(data, dtype="<f8", offset=12)
    out = np.empty((3, 90, 90, 180))
    th, td, pd = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    for c in range(3):  # blocks R, G, B; index = phi_d + 180 * (theta_d + 90 * theta_h)
        out[c] = flat[c * N + pd + 180 * (td + 90 * th)]
    return out


def random_table(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    table = rng.lognormal(0.0, 3.0, TABLE_SHAPE)
    table[rng.random(TABLE_SHAPE) < 0.01] = UNMEASURED_VALUE
    table[0, 0, 0, 0] = -0.0
    table[1, 2, 3, 4] = 5e-324  # a subnormal survives bit-exactly
    return table


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    table = random_table()
    path = write_merl(tmp_path / "t.binary", table)
    back = read_merl(path)
    assert back.values.tobytes() == table.astype("<f8").tobytes()
    assert path.stat().st_size == MERL_FILE_SIZE == 34_992_012


def test_independent_reader_reads_our_files(tmp_path: Path) -> None:
    table = random_table(1)
    path = write_merl(tmp_path / "t.binary", table)
    np.testing.assert_array_equal(independent_read(path), table)


def test_reader_uses_spec_index_order(tmp_path: Path) -> None:
    """Write a file by hand from the spec and check where each value lands."""
    flat = np.arange(3 * N, dtype="<f8")
    path = tmp_path / "hand.binary"
    path.write_bytes(struct.pack("<3i", 90, 90, 180) + flat.tobytes())
    brdf = read_merl(path)
    for c, th, td, pd in [(0, 0, 0, 0), (1, 3, 50, 7), (2, 89, 89, 179)]:
        assert brdf.values[c, th, td, pd] == c * N + pd + 180 * (td + 90 * th)


def test_sha256_of_table_matches_file_bytes(red_plastic_file: Path) -> None:
    brdf = read_merl(red_plastic_file)
    assert brdf.sha256 == hashlib.sha256(red_plastic_file.read_bytes()).hexdigest()
    assert brdf.name == "red-plastic"


def test_negative_values_are_unmeasured_not_data(tmp_path: Path, analytic_tables: dict[str, MerlBRDF]) -> None:
    table = analytic_tables["red-plastic"].values.copy()
    table[0, 10, 10, 10] = -3.5
    brdf = read_merl(write_merl(tmp_path / "t.binary", table))
    assert horizon_mask()[10, 10, 10]
    assert not brdf.mask[0, 10, 10, 10]
    assert brdf.mask[1, 10, 10, 10]
    assert brdf.reflectance()[0, 10, 10, 10] == 0.0
    assert (brdf.reflectance() >= 0).all()


def test_below_horizon_entries_are_invalid(analytic_tables: dict[str, MerlBRDF]) -> None:
    brdf = analytic_tables["white-matte"]
    assert not brdf.mask[:, ~horizon_mask()].any()
    assert brdf.mask[:, horizon_mask()].all()
    assert 0.7 < brdf.valid_fraction < 0.8


# --- bad input -----------------------------------------------------------------


def header(dims: tuple[int, int, int] = (90, 90, 180)) -> bytes:
    return struct.pack("<3i", *dims)


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"", "too short"),
        (b"\x01\x02", "too short"),
        (header() + b"\0" * 100, "truncated"),
        (header((90, 90, 360)) + b"\0" * 100, "dimensions (90, 90, 360)"),
        (header((180, 90, 90)), "dimensions (180, 90, 90)"),
        (b"\x89PNG\r\n\x1a\n" + b"\0" * 5000, "not a MERL"),
        (b"%PDF-1.7\n" + b"x" * 100, "not a MERL"),
    ],
    ids=["empty", "two-bytes", "truncated", "phi-d-360", "axes-swapped", "png", "pdf"],
)
def test_malformed_files_are_rejected_with_the_file_named(tmp_path: Path, content: bytes, expected: str) -> None:
    path = tmp_path / "bad.binary"
    path.write_bytes(content)
    with pytest.raises(MerlFormatError, match=re.escape(expected)) as info:
        read_merl(path)
    assert str(path) in str(info.value)
    assert info.value.path == str(path)


def test_truncated_by_one_byte(tmp_path: Path, red_plastic_file: Path) -> None:
    path = tmp_path / "short.binary"
    path.write_bytes(red_plastic_file.read_bytes()[:-1])
    with pytest.raises(MerlFormatError, match="truncated: 34992011 bytes"):
        read_merl(path)


def test_trailing_bytes(tmp_path: Path, red_plastic_file: Path) -> None:
    path = tmp_path / "long.binary"
    path.write_bytes(red_plastic_file.read_bytes() + b"\0")
    with pytest.raises(MerlFormatError, match="trailing bytes"):
        read_merl(path)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_values_error_or_mask(tmp_path: Path, red_plastic_file: Path, bad: float) -> None:
    data = bytearray(red_plastic_file.read_bytes())
    offset = 12 + 8 * (1 * N + 7 + 180 * (20 + 90 * 30))  # green, θh 30, θd 20, φd 7
    data[offset : offset + 8] = struct.pack("<d", bad)
    path = tmp_path / "nan.binary"
    path.write_bytes(bytes(data))
    with pytest.raises(NonFiniteValueError, match=r"1 NaN or infinite values \(first at .* = \(1, 30, 20, 7\)\)"):
        read_merl(path)
    masked = read_merl(path, nonfinite="mask")
    assert np.isfinite(masked.values).all()
    assert not masked.mask[1, 30, 20, 7]
    assert masked.sha256 == hashlib.sha256(bytes(data)).hexdigest()


def test_directory_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(IsADirectoryError, match=str(tmp_path)):
        read_merl(tmp_path)
    with pytest.raises(FileNotFoundError):
        read_merl(tmp_path / "missing.binary")


def test_invalid_nonfinite_policy(red_plastic_file: Path) -> None:
    with pytest.raises(ValueError, match="nonfinite"):
        read_merl(red_plastic_file, nonfinite="ignore")  # type: ignore[arg-type]


# --- writing --------------------------------------------------------------------


def test_write_refuses_to_overwrite_and_leaves_no_partial_file(tmp_path: Path) -> None:
    table = random_table(2)
    path = write_merl(tmp_path / "t.binary", table)
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="already exists"):
        write_merl(path, table * 2)
    assert path.read_bytes() == before
    write_merl(path, table * 2, overwrite=True)
    np.testing.assert_array_equal(read_merl(path).values, table * 2)
    assert sorted(os.listdir(tmp_path)) == ["t.binary"]


@pytest.mark.parametrize(
    ("table", "message"),
    [
        (np.zeros((3, 90, 90, 90)), "shape"),
        (np.full(TABLE_SHAPE, np.nan), "NaN"),
    ],
)
def test_write_rejects_bad_tables(tmp_path: Path, table: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        write_merl(tmp_path / "t.binary", table)
    assert not any(tmp_path.iterdir())


def test_merlbrdf_validates_its_values() -> None:
    with pytest.raises(ValueError, match="shape"):
        MerlBRDF(np.zeros((3, 90, 90)))
    with pytest.raises(ValueError, match="float64"):
        MerlBRDF(np.zeros(TABLE_SHAPE, dtype=np.float32))


# --- genuine MERL checksums --------------------------------------------------------


def test_genuine_checksums_ship_with_the_package() -> None:
    table = genuine_merl_checksums()
    assert len(table) == 100
    assert all(len(digest) == 64 for digest in table)
    assert "alum-bronze" in table.values() and "green-acrylic" in table.values()


def test_genuine_lookup(red_plastic_file: Path) -> None:
    digest, name = next(iter(genuine_merl_checksums().items()))
    assert genuine_merl_name(digest) == name
    assert genuine_merl_name(digest.upper()) == name
    assert genuine_merl_name(read_merl(red_plastic_file).sha256) is None


@pytest.mark.shared
def test_packaged_checksums_match_shared_list(shared_dir: Path) -> None:
    lines = (shared_dir / "data" / "merl-sha256.txt").read_text().split("\n")
    published = {line.split()[0]: line.split()[1].removesuffix(".binary") for line in lines if line.strip()}
    assert dict(genuine_merl_checksums()) == published
