"""The BLAS thread limit held during decoding: nested and overlapping holders restore the caller's setting."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from brdfcodec.runtime.threads import single_blas_thread

assert np.ones((2, 2)) @ np.ones(2) is not None  # numpy's BLAS is loaded before threadpoolctl looks


def _blas_threads() -> list[int]:
    return [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]


pytestmark = pytest.mark.skipif(not _blas_threads(), reason="numpy's BLAS is not one threadpoolctl can control")


def test_nested_blocks_restore_the_callers_setting() -> None:
    with threadpool_limits(limits=2, user_api="blas"):
        with single_blas_thread():
            with single_blas_thread():
                assert set(_blas_threads()) == {1}
            assert set(_blas_threads()) == {1}
        assert set(_blas_threads()) == {2}


@pytest.mark.parametrize("main_decoded_first", [False, True])
def test_overlapping_blocks_on_two_threads_keep_the_limit_until_the_last_one_ends(main_decoded_first: bool) -> None:
    if main_decoded_first:  # the main thread limited BLAS before (threadpoolctl ≥ 3.6 then gave it "control")
        with single_blas_thread():
            pass
    a_inside, b_inside, a_left, b_checked = (threading.Event() for _ in range(4))
    seen: dict[str, list[int]] = {}

    def first() -> None:
        with single_blas_thread():
            seen["a inside"] = _blas_threads()
            a_inside.set()
            b_inside.wait(10)
        a_left.set()

    def second() -> None:
        a_inside.wait(10)
        with single_blas_thread():
            b_inside.set()
            a_left.wait(10)
            seen["b after a left"] = _blas_threads()
        b_checked.set()

    # The process's own setting (OpenBLAS ignores a setting made by another thread over one made by main).
    before = _blas_threads()
    if max(before) < 2:
        pytest.skip(f"numpy's BLAS runs {before} thread(s) here: nothing to restore")
    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(20)
    assert b_checked.is_set()
    assert set(seen["a inside"]) == {1}  # a block on another thread than main limits too
    assert set(seen["b after a left"]) == {1}  # still limited while the second block runs
    assert _blas_threads() == before  # and the setting from before both is back
