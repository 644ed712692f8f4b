"""The host decode of full tables (issue 51, item 2): ``codec.device_decode.table_from_mapped_host``.

``BrdfDecoder.decode`` (full tables) and ``decode_many`` take it: the float64 exponentials from NumPy or torch
(one library per machine), the steps through each gap and the mask from NumPy. It must give the reference path's table
(``representation.table_from_mapped`` then the mask) up to the last bit of each library's float64 ``exp``, stay
within 1e-6 mapped of a float64 decode (``spec/bvae-format.md`` §9; dark entries, saturated and extreme latents
included), and stay finite.
"""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.codec import BrdfDecoder
from brdfcodec.codec.device_decode import table_from_mapped_host
from brdfcodec.codec.prepare import _apply_mask
from brdfcodec.conventions import MAPPED_MAX, NETWORK_INPUT_SHAPE
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.representation import map_values, table_from_mapped
from brdfcodec.representation.layout import from_network_layout, interpolate_slices
from brdfcodec.representation.mapping import LOG_RANGE
from brdfcodec.representation.mask import horizon_mask

_VALID = np.broadcast_to(horizon_mask(), (3, 90, 90, 180))
#: One float32 rounding apart, at most (the libraries' float64 exp may differ in the last bit).
_ONE_ROUNDING = 2.4e-7


@pytest.fixture(scope="module")
def decoder() -> BrdfDecoder:
    return BrdfDecoder()


@pytest.fixture(scope="module")
def mapped(decoder: BrdfDecoder) -> np.ndarray:
    """Clamped network output of random codes, codes far outside the prior (±1e3, 1e19, −1e23: saturated), and
    a decode with dark rows (values × 1e-4, where the exponential amplifies rounding)."""
    rng = np.random.default_rng(512)
    dim = decoder.latent_dim
    codes = np.stack([rng.standard_normal(dim), rng.standard_normal(dim), np.full(dim, 1e3), np.full(dim, -1e3),
                      np.full(dim, 1e19), np.full(dim, -1e23)]).astype(np.float32)
    out = decoder.decode_mapped(codes)
    dark = out[0].copy()
    dark[:, :30] *= 1e-4
    return np.concatenate([out, dark[None]])


def float64_mapped(mapped: np.ndarray) -> np.ndarray:
    """§6 step 2 in float64: interpolate the kept slices, the mapped table (3, 90, 90, 180)."""
    return interpolate_slices(from_network_layout(mapped.astype(np.float64)))


@pytest.mark.parametrize("masked", ["unmeasured", "zero", "keep"])
@pytest.mark.slow
def test_the_host_decode_is_the_reference_path_s_table(mapped: np.ndarray, masked: str) -> None:
    for slices in mapped:
        got = table_from_mapped_host(slices, masked=masked)  # type: ignore[arg-type]
        want = _apply_mask(table_from_mapped(slices), None, masked)  # type: ignore[arg-type]
        assert got.dtype == np.float32 and got.shape == (3, 90, 90, 180)
        assert np.isfinite(got).all()
        np.testing.assert_allclose(got, want, rtol=_ONE_ROUNDING, atol=0)
        if masked != "keep":
            assert (got[~_VALID] == (-1.0 if masked == "unmeasured" else 0.0)).all()


def test_the_host_decode_is_within_1e_6_mapped_of_float64(mapped: np.ndarray) -> None:
    for slices in mapped[[0, 2, 5, 6]]:  # random, +1e3, -1e23, dark rows
        got = map_values(table_from_mapped_host(slices, masked="keep").astype(np.float64))
        assert float(np.abs(got - float64_mapped(slices))[_VALID].max()) <= 1e-6


def test_the_energy_bound_s_factor_is_applied_after_the_interpolation(mapped: np.ndarray) -> None:
    slices = mapped[0]
    got = table_from_mapped_host(slices, scale=0.37, masked="keep")
    np.testing.assert_allclose(got, table_from_mapped(slices, scale=0.37), rtol=_ONE_ROUNDING, atol=0)
    reference = np.log1p(0.37 * np.expm1(float64_mapped(slices) * LOG_RANGE)) / LOG_RANGE
    assert float(np.abs(map_values(got.astype(np.float64)) - reference)[_VALID].max()) <= 1e-6


def test_the_domain_s_ends_and_float16_slices_decode(mapped: np.ndarray) -> None:
    for value in (0.0, MAPPED_MAX):
        slices = np.full(NETWORK_INPUT_SHAPE, value, dtype=np.float32)
        got = table_from_mapped_host(slices, masked="keep")
        assert np.isfinite(got).all()
        np.testing.assert_allclose(got, table_from_mapped(slices), rtol=_ONE_ROUNDING, atol=0)
    half = mapped[0].astype(np.float16)
    got = table_from_mapped_host(half)  # type: ignore[arg-type]
    np.testing.assert_allclose(got, _apply_mask(table_from_mapped(half.astype(np.float32)), None, "unmeasured"),
                               rtol=_ONE_ROUNDING, atol=0)
    read_only = mapped[1].copy()
    read_only.setflags(write=False)
    np.testing.assert_array_equal(table_from_mapped_host(read_only), table_from_mapped_host(mapped[1].copy()))


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"masked": "nan"}, "masked must be"),
    ({"scale": float("nan")}, "scale must be"),
    ({"scale": -1.0}, "scale must be"),
])
def test_bad_arguments_are_refused(mapped: np.ndarray, kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        table_from_mapped_host(mapped[0], **kwargs)


def test_a_wrong_shape_is_refused() -> None:
    with pytest.raises(ValueError, match="mapped must have shape"):
        table_from_mapped_host(np.zeros((3, 90, 90, 21), dtype=np.float32))


def test_decode_and_decode_many_give_the_reference_path_s_table(decoder: BrdfDecoder) -> None:
    codes = np.random.default_rng(7).standard_normal((3, decoder.latent_dim)).astype(np.float32)
    records = [LatentRecord(f"m{i}", code, np.ones(decoder.latent_dim, np.float32)) for i, code in enumerate(codes)]
    many = list(decoder.decode_many(records, batch_size=2))
    for record, table, slices in zip(records, many, decoder.decode_mapped(codes, batch_size=2), strict=True):
        want = _apply_mask(table_from_mapped(slices), None, "unmeasured")
        np.testing.assert_allclose(table, want, rtol=_ONE_ROUNDING, atol=0)
        alone = _apply_mask(table_from_mapped(decoder.decode_mapped(record.mu)), None, "unmeasured")
        np.testing.assert_allclose(decoder.decode(record), alone, rtol=_ONE_ROUNDING, atol=0)  # a batch of one


def test_stepped_table_fills_exactly_the_invalid_bins_it_is_given(mapped: np.ndarray) -> None:
    """Any mask, not only the horizon's (whose invalid bins are a suffix of θd in each θh row): the blocks' spans
    of invalid columns are found, and a writable mask is read afresh on each call."""
    from brdfcodec.representation.network_io import _STORED_PER_EXPM1, _kept_exponentials, stepped_table

    start, ratio = _kept_exponentials(from_network_layout(mapped[0]), _STORED_PER_EXPM1.reshape(3, 1, 1, 1))
    whole = stepped_table(start, ratio, _STORED_PER_EXPM1)
    invalid = np.zeros((90, 90, 180), dtype=bool)
    invalid[3, 5, 7] = invalid[44, 0, 179] = invalid[89, 89, 0] = True
    invalid[60:62, 10:12, 90:100] = True
    got = stepped_table(start, ratio, _STORED_PER_EXPM1, invalid=invalid, fill=-1.0)
    np.testing.assert_array_equal(got, np.where(invalid, np.float32(-1.0), whole))
    invalid[:] = False
    invalid[0, 0, 0] = True
    got = stepped_table(start, ratio, _STORED_PER_EXPM1, invalid=invalid, fill=-1.0)
    np.testing.assert_array_equal(got, np.where(invalid, np.float32(-1.0), whole))
    invalid.setflags(write=False)
    for _ in range(2):  # cached on the second call
        got = stepped_table(start, ratio, _STORED_PER_EXPM1, invalid=invalid, fill=0.0)
        np.testing.assert_array_equal(got, np.where(invalid, np.float32(0.0), whole))


def test_the_table_is_written_where_asked(mapped: np.ndarray) -> None:
    target = np.full((3, 90, 90, 180), np.nan, dtype=np.float32)
    assert table_from_mapped_host(mapped[1], out=target) is target
    np.testing.assert_array_equal(target, table_from_mapped_host(mapped[1]))
    for wrong in (np.empty((3, 90, 90, 179), np.float32), np.empty((3, 90, 90, 180), np.float64),
                  np.empty((3, 90, 90, 360), np.float32)[..., ::2]):
        with pytest.raises(ValueError, match="out must be"):
            table_from_mapped_host(mapped[1], out=wrong)


def test_the_cpu_network_takes_at_most_two_codes_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """``BrdfDecoder.network_batch``: the batched decodes on the CPU give the network pairs of codes, whatever
    ``batch_size`` asks (its buffers then stay below glibc's mmap threshold); the tables are unchanged."""
    from brdfcodec.codec.decoder import CPU_NETWORK_BATCH

    decoder = BrdfDecoder()
    assert CPU_NETWORK_BATCH == 2
    assert [decoder.network_batch(n) for n in (1, 2, 16)] == [1, 2, 2]
    with pytest.raises(ValueError, match="at least 1"):
        decoder.network_batch(0)
    codes = np.random.default_rng(12).standard_normal((5, decoder.latent_dim)).astype(np.float32)
    records = [LatentRecord(f"m{i}", code, np.ones(decoder.latent_dim, np.float32)) for i, code in enumerate(codes)]
    expected = [decoder.decode(record) for record in records]
    sizes: list[int] = []
    forward = type(decoder.network).forward

    def counting(network, z):  # noqa: ANN001, ANN202 - the network's forward, counted
        sizes.append(len(z))
        return forward(network, z)

    monkeypatch.setattr(type(decoder.network), "forward", counting)
    tables = list(decoder.decode_many(records, batch_size=16))
    assert sizes == [2, 2, 1]
    for table, single in zip(tables, expected, strict=True):  # the network's rounding in pairs, not alone
        assert np.array_equal(table < 0, single < 0)
        valid = np.broadcast_to(single >= 0, single.shape)
        np.testing.assert_allclose(map_values(table)[valid], map_values(single)[valid], rtol=0, atol=1e-5)
    sizes.clear()
    decoder.decode_many_tensor(codes, batch_size=16)
    assert sizes == [2, 2, 1]
