"""The compiled passes of the host decode (``representation/stepped_kernel.py``, issue 51 item 2) give the NumPy and
torch paths' output bit for bit: same operations, same order, no fast-math."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.codec.device_decode import _invalid_bins, table_from_mapped_host
from brdfcodec.representation import stepped_kernel
from brdfcodec.representation.network_io import stepped_table
from brdfcodec.representation.stepped_kernel import invalid_runs, whole_gaps

pytest.importorskip("numba", reason="numba is a dependency; without it the compiled passes are not used")


@pytest.fixture
def without_compiled_passes(monkeypatch: pytest.MonkeyPatch):  # noqa: ANN201
    """Inside: the NumPy and torch paths (BRDFCODEC_NO_JIT=1); the compiled kernels again after."""

    def clear() -> None:
        stepped_kernel.compiled_stepping.cache_clear()
        stepped_kernel.compiled_log_arguments.cache_clear()

    class Switch:
        def __enter__(self) -> None:
            monkeypatch.setenv(stepped_kernel.DISABLE_VARIABLE, "1")
            clear()

        def __exit__(self, *exc: object) -> None:
            monkeypatch.delenv(stepped_kernel.DISABLE_VARIABLE)
            clear()

    yield Switch()
    clear()


def _bits(array: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(array).view(np.uint32)


@pytest.mark.parametrize("masked", [True, False])
def test_the_compiled_stepping_is_the_numpy_steps_bit_for_bit(without_compiled_passes, masked: bool) -> None:  # noqa: ANN001
    rng = np.random.default_rng(3)
    # steep gaps, tiny and huge values: where the float64 steps and the one rounding to float32 can differ
    start = np.exp(rng.standard_normal((2, 3, 90, 90, 21)) * 8.0)
    ratio = np.exp(rng.standard_normal((2, 3, 90, 90, 20)))
    factor = np.array([1e-3, 0.7, 2.0])
    invalid = _invalid_bins() if masked else None
    compiled = stepped_table(start, ratio, factor, invalid=invalid, fill=-1.0, compiled=True)
    assert stepped_kernel.compiled_stepping() is not None
    reference = stepped_table(start, ratio, factor, invalid=invalid, fill=-1.0)  # the NumPy path by default
    np.testing.assert_array_equal(_bits(compiled), _bits(reference))
    with without_compiled_passes:  # asked for, but switched off: the NumPy path
        assert stepped_kernel.compiled_stepping() is None
        np.testing.assert_array_equal(
            _bits(stepped_table(start, ratio, factor, invalid=invalid, fill=-1.0, compiled=True)), _bits(reference))
    # the rows split over threads write the same table
    np.testing.assert_array_equal(
        _bits(stepped_table(start, ratio, factor, invalid=invalid, fill=-1.0, compiled=True, threads=3)),
        _bits(reference))


def test_the_host_decode_is_the_same_with_and_without_the_compiled_passes() -> None:
    rng = np.random.default_rng(4)
    mapped = (rng.random((63, 90, 90)) * 1.2).astype(np.float32)
    mapped[:, :5] = 0.0  # flat dark rows and a saturated corner
    mapped[:, -3:, -3:] = 1.9
    for masked in ("unmeasured", "zero", "keep"):
        compiled = table_from_mapped_host(mapped, scale=0.8, masked=masked, compiled=True)
        reference = table_from_mapped_host(mapped, scale=0.8, masked=masked)
        np.testing.assert_array_equal(_bits(compiled), _bits(reference))


def test_decode_many_and_decode_give_the_same_tables() -> None:
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import LatentRecord

    decoder = BrdfDecoder()
    codes = np.random.default_rng(5).standard_normal((3, decoder.latent_dim)).astype(np.float32) * 2.5
    records = [LatentRecord(f"m{i}", code, np.ones(decoder.latent_dim, np.float32)) for i, code in enumerate(codes)]
    for record, table in zip(records, decoder.decode_many(records, batch_size=1), strict=True):
        np.testing.assert_array_equal(_bits(table), _bits(decoder.decode(record)))


def test_invalid_runs_cover_exactly_the_invalid_bins() -> None:
    invalid = _invalid_bins()
    runs = invalid_runs(invalid)
    rebuilt = np.zeros_like(invalid)
    for h, d, r in np.ndindex(*runs.shape[:3]):
        low, high = runs[h, d, r]
        rebuilt[h, d, low:high] = True
    np.testing.assert_array_equal(rebuilt, invalid)
    assert invalid_runs(np.zeros((2, 2, 5), dtype=bool)).shape == (2, 2, 1, 2)


def test_whole_gaps_are_the_gaps_whose_nine_bins_are_all_invalid() -> None:
    invalid = np.zeros((2, 3, 180), dtype=bool)
    invalid[0, 0, 9:18] = True  # gap 1, whole
    invalid[0, 1, 10:18] = True  # gap 1 less its first bin: not whole
    invalid[1, 2, 171:180] = True  # the last gap, bin 179 included
    whole = whole_gaps(invalid)
    assert whole.shape == (2, 3, 20)
    assert [tuple(index) for index in np.argwhere(whole)] == [(0, 0, 1), (1, 2, 19)]
    np.testing.assert_array_equal(whole_gaps(_invalid_bins()),
                                  _invalid_bins().reshape(90, 90, 20, 9).all(axis=-1))


def test_a_mask_over_whole_gaps_and_the_last_bin_is_filled_by_the_compiled_pass() -> None:
    """Gaps wholly invalid are filled without being stepped, and the last bin (written again from the last kept
    slice) is still filled: the NumPy path's table, bit for bit."""
    rng = np.random.default_rng(9)
    start = np.exp(rng.standard_normal((3, 90, 90, 21)))
    ratio = np.exp(rng.standard_normal((3, 90, 90, 20)) * 0.1)
    factor = np.array([1e-3, 0.7, 2.0])
    invalid = np.zeros((90, 90, 180), dtype=bool)
    invalid[:, :45, 162:] = True  # the last two gaps, bin 179 with them
    invalid[:, 45:, 10:30] = True  # part of gap 1, gap 2 whole, part of gap 3
    invalid.setflags(write=False)
    compiled = stepped_table(start, ratio, factor, invalid=invalid, fill=-1.0, compiled=True)
    reference = stepped_table(start, ratio, factor, invalid=invalid, fill=-1.0)
    np.testing.assert_array_equal(_bits(compiled), _bits(reference))
    assert (compiled[:, :, :45, 162:] == -1.0).all() and (compiled[:, :, 45:, 10:30] == -1.0).all()


def test_the_host_decode_takes_one_exp_on_both_paths_whichever_library(monkeypatch: pytest.MonkeyPatch) -> None:
    """Torch's float64 exp where NumPy's is not vectorised, NumPy's where it is: the single decode (no compiled
    passes) and the batch decode's (compiled) give the same bits either way, within an ulp of each other."""
    from brdfcodec.codec import device_decode

    rng = np.random.default_rng(10)
    mapped = (rng.random((63, 90, 90)) * 1.4).astype(np.float32)
    tables = {}
    for vectorised in (True, False):
        monkeypatch.setattr(device_decode, "_numpy_exp_is_vectorised", lambda v=vectorised: v)
        single = table_from_mapped_host(mapped, scale=0.7)
        batch = table_from_mapped_host(mapped, scale=0.7, compiled=True)
        np.testing.assert_array_equal(_bits(batch), _bits(single))
        tables[vectorised] = single
    valid = tables[True] >= 0
    np.testing.assert_allclose(tables[False][valid], tables[True][valid], rtol=1e-6, atol=1e-12)


def _not_compilable(value: object) -> None:
    print(object(), value)  # an arbitrary Python object: Numba's nopython mode refuses it


def test_a_kernel_numba_cannot_compile_leaves_the_numpy_path_with_a_warning() -> None:
    with pytest.warns(RuntimeWarning, match="compiled decode passes are unavailable"):
        assert stepped_kernel._compiled(_not_compilable, 1) is None


def test_batch_decodes_on_two_threads_at_once_give_each_its_own_tables() -> None:
    """The compiled passes' working arrays are per thread: two threads decoding at once do not mix them."""
    from concurrent.futures import ThreadPoolExecutor

    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import LatentRecord

    decoder = BrdfDecoder()
    codes = np.random.default_rng(6).standard_normal((4, decoder.latent_dim)).astype(np.float32)
    records = [LatentRecord(f"m{i}", code, np.ones(decoder.latent_dim, np.float32)) for i, code in enumerate(codes)]
    expected = [_bits(decoder.decode(record)) for record in records]
    with ThreadPoolExecutor(2) as pool:
        halves = list(pool.map(lambda part: list(decoder.decode_many(part, batch_size=1)), [records[:2], records[2:]]))
    for table, bits in zip(halves[0] + halves[1], expected, strict=True):
        np.testing.assert_array_equal(_bits(table), bits)


def test_the_host_decode_split_over_two_threads_is_the_same_table(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a machine whose codec runs one thread the row split of the compiled passes never runs: run it here."""
    from brdfcodec.runtime import threads

    if threads.available_cores() < 2:
        pytest.skip("one core: the codec runs one thread, its rows are not split")
    monkeypatch.setattr(threads, "_chosen", None)  # restored after the test
    rng = np.random.default_rng(8)
    mapped = (rng.random((63, 90, 90)) * 1.5).astype(np.float32)
    threads.set_num_threads(1)
    one = table_from_mapped_host(mapped, scale=0.9, compiled=True)
    threads.set_num_threads(2)
    two = table_from_mapped_host(mapped, scale=0.9, compiled=True)
    np.testing.assert_array_equal(_bits(two), _bits(one))


def _decode_in_child() -> None:
    """The batch decodes' host passes (compiled: no torch operation, whose OpenMP pool is torch's own matter)."""
    mapped = (np.random.default_rng(13).random((63, 90, 90)) * 1.5).astype(np.float32)
    table_from_mapped_host(mapped, compiled=True)


def test_a_forked_child_decodes_after_its_parent_split_rows_over_threads(monkeypatch: pytest.MonkeyPatch) -> None:
    """The row pool's threads do not survive a fork: a child (a DataLoader worker, multiprocessing's fork start
    method) gets a pool of its own instead of waiting forever on the parent's."""
    import multiprocessing

    from brdfcodec.runtime import threads

    if "fork" not in multiprocessing.get_all_start_methods():
        pytest.skip("no fork on this platform")
    monkeypatch.setattr(threads, "_chosen", None)  # restored after the test
    threads.set_num_threads(2)  # the rows split over a pool, even on one core
    _decode_in_child()  # the parent's pool started
    child = multiprocessing.get_context("fork").Process(target=_decode_in_child)
    child.start()
    child.join(timeout=120)
    if child.is_alive():
        child.kill()
        pytest.fail("the forked child's decode did not finish within 120 s (the parent's pool inherited)")
    assert child.exitcode == 0
