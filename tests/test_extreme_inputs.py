"""Stiff and extreme MERL tables (issue 49, R3-17): defined, honest results and no NumPy warnings.

Each table goes through the public API (encode, measure, decode) or the CLI: the decode is finite with no
negative entry besides the −1 mask, the error report is defined (a RelAE, or for a near-black source an
absolute error), and no ``RuntimeWarning`` (NumPy's overflow / invalid-value warnings) escapes.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.conventions import TABLE_SHAPE
from brdfcodec.errors import RateTargetError
from brdfcodec.io.merl import MerlBRDF, write_merl
from brdfcodec.representation.mask import horizon_mask
from brdfcodec.representation.metrics import (
    NEAR_BLACK_REFLECTANCE,
    RelaeAgainst,
    mean_absolute_error,
    near_black,
    relae_both,
)

SCALE = np.array([1.0, 1.15, 1.66]) / 1500.0  # stored × scale = reflectance (1/sr)


def _constant(value: float) -> Callable[[], np.ndarray]:
    return lambda: np.full(TABLE_SHAPE, value)


def _spike() -> np.ndarray:
    table = np.zeros(TABLE_SHAPE)
    table[:, 0:2, 0:3] = 1e6
    return table


def _one_channel() -> np.ndarray:  # red only
    table = np.zeros(TABLE_SHAPE)
    table[0] = 0.05 / SCALE[0]
    return table


def _one_valid_entry() -> np.ndarray:
    table = np.full(TABLE_SHAPE, -1.0)
    table[:, 10, 20, 30] = 0.2 / SCALE
    return table


#: name → table in stored units; "black" ones have every valid entry below NEAR_BLACK_REFLECTANCE.
TABLES: dict[str, tuple[Callable[[], np.ndarray], bool]] = {
    "zeros": (_constant(0.0), True),
    "denormal": (_constant(5e-324), True),
    "denormal-1e-310": (_constant(1e-310), True),
    "tiny-1e-30": (_constant(1e-30), True),
    "huge-1e300": (_constant(1e300), False),
    "spike-1e6": (_spike, False),
    "one-channel": (_one_channel, False),
    "one-valid-entry": (_one_valid_entry, False),
    "albedo-far-above-1": (lambda: np.full(TABLE_SHAPE, 1e4) / SCALE[:, None, None, None], False),
}


@pytest.fixture(autouse=True)
def _numpy_warnings_are_errors() -> Iterator[None]:
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # 'overflow encountered in divide' and the like
        yield


def _source(name: str) -> MerlBRDF:
    return MerlBRDF(TABLES[name][0](), name=name)


# --------------------------------------------------------------------------------------------- metrics


@pytest.mark.parametrize("name", list(TABLES))
@pytest.mark.slow
def test_relae_is_defined_exactly_when_the_source_is_not_near_black(name: str) -> None:
    source = _source(name)
    values, mask = source.values, source.mask
    estimate = np.where(mask, 0.5 * np.abs(values).clip(max=1e8) + 0.01, -1.0)
    linear, mapped = relae_both(values, estimate, mask)
    black = TABLES[name][1]
    assert near_black(values, mask) is black
    assert RelaeAgainst(values, mask).defined is not black
    if black:  # a ratio to (nearly) nothing: undefined, never 1e30
        assert np.isnan(linear.overall) and np.isnan(mapped.overall)
        error = mean_absolute_error(values, estimate, mask)
        assert np.isfinite(error.overall) and error.overall > 0
    else:
        assert np.isfinite(linear.overall) and np.isfinite(mapped.overall)
        assert 0 <= mapped.overall < 10


def test_near_black_floor_is_the_reflectance_floor() -> None:
    just_below = np.full(TABLE_SHAPE, 0.9 * NEAR_BLACK_REFLECTANCE) / SCALE[:, None, None, None]
    just_above = np.full(TABLE_SHAPE, 1.1 * NEAR_BLACK_REFLECTANCE) / SCALE[:, None, None, None]
    assert near_black(just_below) and not near_black(just_above)
    assert np.isfinite(relae_both(just_above, 2 * just_above)[1].overall)


def test_a_black_channel_counts_in_the_overall_error() -> None:
    table = _one_channel()
    estimate = table.copy()
    estimate[1] = 0.1 / SCALE[1]  # green lit where the source has none
    linear, _ = relae_both(table, estimate)
    assert np.isnan(linear.green) and linear.overall > 1.0  # the green error is not hidden


# --------------------------------------------------------------------------------------------- codec


@pytest.fixture(scope="module")
def codec() -> tuple[object, object]:
    from brdfcodec.codec import BrdfDecoder, BrdfEncoder

    decoder = BrdfDecoder()
    return BrdfEncoder(), decoder


def _check_decode(decoded: np.ndarray) -> None:
    assert np.isfinite(decoded).all()
    assert ((decoded >= 0) | (decoded == -1)).all()


@pytest.mark.parametrize("name", list(TABLES))
@pytest.mark.slow
def test_extreme_table_encodes_and_reports_honestly(name: str, codec: tuple) -> None:
    from brdfcodec.codec import encode_records

    encoder, decoder = codec
    source = _source(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the clamp of 1e300 and "RelAE undefined" are bvae's own
        record = encode_records([source], encoder=encoder, decoder=decoder)[0]
    decoded = decoder.decode(record, masked="keep").astype(np.float64)
    _check_decode(decoded)
    if TABLES[name][1]:  # near black: decodes black, no RelAE, an absolute error below the floor
        assert "relae" not in record.meta
        lit = horizon_mask()[None].repeat(3, axis=0)
        assert not decoded[lit].any()
        assert mean_absolute_error(source.values, decoded, source.mask).overall < NEAR_BLACK_REFLECTANCE
    else:
        relae = record.meta["relae"]
        assert all(np.isfinite(v) and 0 <= v < 1e3 for v in relae.values())


@pytest.mark.slow
@pytest.mark.parametrize("name", ["zeros", "tiny-1e-30", "spike-1e6"])
def test_extreme_table_under_a_budget(name: str) -> None:
    from brdfcodec.codec import BrdfDecoder, BrdfEncoder, encode_records

    decoder = BrdfDecoder()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        record = encode_records([_source(name)], encoder=BrdfEncoder(bytes=96), decoder=decoder)[0]
    decoded = decoder.decode(record, masked="keep")
    _check_decode(decoded)
    if TABLES[name][1]:
        assert not decoded[decoded > 0].any()
    else:
        assert np.isfinite(record.meta["relae"]["mapped"])


def test_black_record_fits_a_budget_or_steps_aside(codec: tuple) -> None:
    from brdfcodec.codec.black import black_record
    from brdfcodec.format.bvae import LatentRecord
    from brdfcodec.format.writer import record_size

    _, decoder = codec
    base = LatentRecord("black", np.full(8, 0.3, np.float32), np.ones(8, np.float32), {})
    full = black_record(base)
    assert full is not None and not full.compact_mu
    assert not (decoder.decode(full) > 0).any()  # exactly black, whatever the base code
    small = black_record(base, bytes_budget=record_size(full) - 1)
    assert small is not None and small.compact_mu and record_size(small) < record_size(full)
    assert not (decoder.decode(small) > 0).any()
    assert black_record(base, bytes_budget=8) is None


@pytest.mark.slow
def test_unreachable_error_target_names_the_best_error(codec: tuple) -> None:
    from brdfcodec.codec import BrdfEncoder, encode_records

    _, decoder = codec
    rng = np.random.default_rng(0)
    noisy = MerlBRDF(np.exp(rng.normal(0.0, 5.0, TABLE_SHAPE)) * 1e-3, name="noise")
    with pytest.raises(RateTargetError, match=r"the best RelAE reached is \d") as caught:
        encode_records([noisy], encoder=BrdfEncoder(max_relae=1e-4), decoder=decoder)
    assert "nan" not in str(caught.value)


# --------------------------------------------------------------------------------------------- CLI


def test_cli_black_source_reports_an_absolute_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from brdfcodec.cli import main

    write_merl(tmp_path / "black.binary", np.zeros(TABLE_SHAPE))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        assert main(["compress", str(tmp_path / "black.binary"), "-o", str(tmp_path / "b.bvae")]) == 0
    out = capsys.readouterr().out
    assert "mean absolute error 0 /sr" in out and "RelAE mapped" not in out
    assert main(["decompress", str(tmp_path / "b.bvae"), "-o", str(tmp_path / "b.npy")]) == 0
    decoded = np.load(tmp_path / "b.npy")
    assert decoded.max() == 0.0 and ((decoded == 0) | (decoded == -1)).all()


@pytest.mark.parametrize("value", ["inf", "nan", "0.5,-inf"])
def test_cli_edit_refuses_non_finite_weights(tmp_path: Path, value: str, capsys: pytest.CaptureFixture[str]) -> None:
    from brdfcodec.cli import main

    code = main(["edit", "interp", str(tmp_path / "x.bvae"), "a", "b", f"--t={value}", "-o", str(tmp_path / "o.bvae")])
    assert code == 2
    assert "--t" in capsys.readouterr().err
    assert not (tmp_path / "o.bvae").exists()


def test_interpolate_refuses_a_non_finite_weight() -> None:
    from brdfcodec.edit.latent_edits import interpolate
    from brdfcodec.format.bvae import LatentRecord

    a = LatentRecord("a", np.zeros(8, np.float32), np.ones(8, np.float32), {})
    with pytest.raises(ValueError, match="t must be finite"):
        interpolate(a, a, float("inf"))
