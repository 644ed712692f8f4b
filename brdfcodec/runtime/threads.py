"""The library's threads: how many torch uses in brdfcodec's calls, and numpy's BLAS on one thread meanwhile.

**One setting.** :func:`set_num_threads` (or the environment variable
``BVAE_NUM_THREADS``, then ``OMP_NUM_THREADS``) chooses how many threads
torch runs on inside brdfcodec's encode and decode calls, at most the cores the
process may use (:func:`available_cores`: a larger count is limited to them, with a
:class:`ThreadCountWarning`); by default half
the cores, at least 1 and at most :data:`MAX_DEFAULT_THREADS`, as the
``bvae`` command line uses. The count is applied on the calling thread for
the duration of each call and the caller's own torch setting is restored
afterwards (:func:`codec_threads`).

Why not torch's default (every core): torch's intra-op threads are OpenMP
workers that meet at a barrier after every operation and spin while they
wait. Refinement and the basis fit run thousands of small operations on one
material; beside other CPU-bound processes (a renderer's own threads, a
training job) a worker that is descheduled holds every barrier up while the
others spin on the cores the work needs, so that on a busy machine with few
cores an encode with more torch threads can take far longer than with one
(the benchmark suite's ``encode-16KB-busy`` group; documentation: Development).

**BLAS.** Decoding and encoding run torch and numpy's BLAS
(basis sum, inverse DCT of the detail layer, slice interpolation) one after
the other. OpenBLAS' worker threads keep spinning for a while after each
call, so on a machine with few cores they take the cores torch's threads
need next: with few cores a layered decode is slower with BLAS threaded
than with BLAS on one thread, while a base-only decode is not (the benchmark
suite's ``decode-layered`` groups; documentation: Development). The limit
is set for the duration of a call only, through threadpoolctl (whose scan
of the loaded libraries is made once, and again only after new imports), and the
caller's own BLAS setting is restored afterwards; decodes that overlap on
several threads share one limit (:class:`~brdfcodec.runtime.shared_limit.SharedLimit`).
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from brdfcodec.runtime.shared_limit import SharedLimit

__all__ = [
    "MAX_DEFAULT_THREADS", "ThreadCountWarning", "available_cores", "codec_threads", "default_thread_count",
    "environment_thread_count", "get_num_threads", "set_num_threads", "single_blas_thread",
]

#: Most threads brdfcodec gives torch by default.
MAX_DEFAULT_THREADS = 8
#: The count chosen with :func:`set_num_threads` (None: from the environment, else the default).
_chosen: int | None = None
_local = threading.local()


def default_thread_count(cpu_count: int | None = None) -> int:
    """Threads by default: half the cores, at least 1, at most :data:`MAX_DEFAULT_THREADS`."""
    cores = cpu_count if cpu_count is not None else (os.cpu_count() or 1)
    return max(1, min(MAX_DEFAULT_THREADS, cores // 2))


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system says, else the machine's), ≥ 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


class ThreadCountWarning(UserWarning):
    """A thread count asked for was more than the cores this process may use; the cores were used instead."""


def _clamped(count: int, source: str) -> int:
    """``count`` limited to :func:`available_cores`, with a :class:`ThreadCountWarning` naming ``source`` when
    it was more: OpenMP allocates per thread up front, and a count such as 999999999 ends the process in
    libgomp ("Out of memory allocating …", or "Thread creation failed") with no message of ours."""
    cores = available_cores()
    if count <= cores:
        return count
    import warnings

    warnings.warn(f"{source}={count} asks for more threads than the {cores} cores this process may use; "
                  f"using {cores}", ThreadCountWarning, stacklevel=3)
    return cores


def _positive(text: str | None) -> int | None:
    try:
        count = int((text or "").strip())
    except ValueError:
        return None
    return count if count >= 1 else None


def environment_thread_count(environ: Mapping[str, str] | None = None) -> int | None:
    """The thread count the environment asks for: ``BVAE_NUM_THREADS``, else ``OMP_NUM_THREADS``, each used only
    when it is a positive integer, limited to :func:`available_cores` (with a :class:`ThreadCountWarning` naming
    the variable); None when neither holds one."""
    env = os.environ if environ is None else environ
    for name in ("BVAE_NUM_THREADS", "OMP_NUM_THREADS"):
        count = _positive(env.get(name))
        if count is not None:
            return _clamped(count, name)
    return None


def set_num_threads(count: int | None) -> None:
    """Choose how many threads torch runs on inside brdfcodec's calls (encode, decode, rate control).

    Parameters
    ----------
    count : int or None
        A positive number of threads, or None to go back to the environment
        (``BVAE_NUM_THREADS``, then ``OMP_NUM_THREADS``) and else the default,
        :func:`default_thread_count`. More than :func:`available_cores` is
        limited to them (:class:`ThreadCountWarning`).

    Raises
    ------
    ValueError
        ``count`` is not a positive integer.
    """
    global _chosen
    if count is not None and (isinstance(count, bool) or not isinstance(count, int) or count < 1):
        raise ValueError(f"the number of threads must be a positive integer or None, got {count!r}")
    _chosen = None if count is None else _clamped(count, "set_num_threads")


def get_num_threads(environ: Mapping[str, str] | None = None) -> int:
    """How many threads torch runs on inside brdfcodec's calls.

    :func:`set_num_threads` wins, then ``BVAE_NUM_THREADS``, then
    ``OMP_NUM_THREADS``, then :func:`default_thread_count` (a value that is
    not a positive integer is ignored; one above :func:`available_cores` is
    limited to them, :func:`environment_thread_count`).
    """
    if _chosen is not None:
        return _chosen
    count = environment_thread_count(environ)
    return default_thread_count() if count is None else count


@contextlib.contextmanager
def _torch_threads(count: int) -> Iterator[None]:
    """torch on ``count`` intra-op threads in the enclosed block, on the calling thread (OpenMP's setting is the
    thread's own); the thread's previous count is restored when its outermost block ends."""
    torch = sys.modules.get("torch")
    depth = getattr(_local, "depth", 0)
    if torch is None or depth:
        _local.depth = depth + 1
        try:
            yield
        finally:
            _local.depth = depth
        return
    previous = torch.get_num_threads()
    if previous != count:
        torch.set_num_threads(count)
    _local.depth = 1
    try:
        yield
    finally:
        _local.depth = 0
        if previous != count:
            torch.set_num_threads(previous)


@contextlib.contextmanager
def codec_threads() -> Iterator[None]:
    """Run the enclosed block as brdfcodec's calls run: torch on :func:`get_num_threads` threads (on the calling
    thread; restored after), numpy's BLAS on one (:func:`single_blas_thread`). Safe to nest."""
    with single_blas_thread(), _torch_threads(get_num_threads()):
        yield


_scanned: tuple[int, Any] | None = None


def _controller() -> Any:
    """The BLAS libraries loaded in the process, scanned once and again only after new modules were imported.

    A scan (threadpoolctl walks every loaded shared library and ``stat``s it) costs milliseconds, as much as
    the rest of a decode's bookkeeping; a BLAS library loaded since the last scan (scipy's own OpenBLAS, say)
    comes with an import, so ``len(sys.modules)`` changing is when to scan again. Called under
    :class:`SharedLimit`'s lock.
    """
    global _scanned
    modules = len(sys.modules)
    if _scanned is None or _scanned[0] != modules:
        from threadpoolctl import ThreadpoolController

        _scanned = (modules, ThreadpoolController())
        _scanned = (len(sys.modules), _scanned[1])  # the scan's own imports do not call for another
    return _scanned[1]


def _release_openblas_control() -> None:
    """Let any thread set OpenBLAS' thread count next.

    threadpoolctl ≥ 3.6 lets only one "controlling" Python thread change a
    process-wide OpenBLAS pool (others are silently ignored), and a limit not
    used as a ``with`` block keeps that control. Our sets and restores are
    serialised by :class:`SharedLimit`'s lock, so control is released around each of them.
    """
    import threadpoolctl

    clear = getattr(getattr(threadpoolctl, "OpenBLASController", None), "clear_controlling_thread", None)
    if clear is not None:
        clear(force=True)


def _limit_blas_to_one_thread() -> Callable[[], None]:
    _release_openblas_control()
    limiter = _controller().limit(limits=1, user_api="blas")
    _release_openblas_control()

    def restore() -> None:
        _release_openblas_control()
        limiter.restore_original_limits()
        _release_openblas_control()

    return restore


_ONE_BLAS_THREAD = SharedLimit(_limit_blas_to_one_thread)


def single_blas_thread() -> contextlib.AbstractContextManager[None]:
    """Run the enclosed block with numpy's BLAS limited to one thread (torch's threads are untouched).

    Safe to nest and to enter from several threads at once: the BLAS setting
    found when the first block began is restored when the last one ends.
    The BLAS libraries are those loaded when the outermost block begins (numpy's, and any other, such as scipy's).
    """
    return _ONE_BLAS_THREAD.held()
