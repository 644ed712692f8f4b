"""Entry point of ``bvae``: argument parsing and error reporting.

Each sub-command lives in its own module with ``register(subparsers)``; its
handler returns an exit code. Errors about data or files are printed as one
line naming the file and the problem; nothing prints a traceback unless
``BVAE_DEBUG=1`` is set. Exit codes (``docs/cli-notes.md``, on the command-line reference page):

====  ==========================================================
0     success
1     bad input: a malformed or missing file, an output that exists
2     usage: arguments argparse refuses, or that make no sense together
3     internal error (a bug: please report it)
130   interrupted (Ctrl-C, SIGINT)
141   standard output closed early (``bvae info f.bvae | head``): quiet, like other tools
143   terminated (SIGTERM); partial outputs are removed in every case
====  ==========================================================

Threads: torch's intra-op thread pool is sized for one process per machine,
so several ``bvae`` processes on a small machine oversubscribe it. ``bvae`` therefore
uses half the cores (at least 1, at most 8) unless ``BVAE_NUM_THREADS`` or
``OMP_NUM_THREADS`` says otherwise.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import signal
import sys
import warnings
from collections.abc import Iterator, Sequence

from brdfcodec.cli import (
    analytic_command,
    bench_command,
    compress_command,
    dataset_command,
    decompress_command,
    edit_command,
    extract_command,
    info_command,
    model_command,
    render_command,
    studio_command,
    train_command,
)
from brdfcodec.cli.usage import UsageError
from brdfcodec.errors import BrdfcodecError
from brdfcodec.io.atomic import remove_unfinished_outputs
from brdfcodec.runtime.threads import (
    MAX_DEFAULT_THREADS,
    ThreadCountWarning,
    default_thread_count,
    environment_thread_count,
)
from brdfcodec.version import __version__

__all__ = ["MAX_DEFAULT_THREADS", "build_parser", "configure_threads", "default_thread_count", "main"]

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 128 + 13
EXIT_TERMINATED = 128 + 15

class Terminated(BaseException):
    """SIGTERM arrived: unwinds like ``KeyboardInterrupt`` so that partial outputs are removed."""


def configure_threads(environ: dict[str, str] | None = None) -> int:
    """Choose the thread count of a ``bvae`` run and apply it; return it.

    ``BVAE_NUM_THREADS`` wins, then ``OMP_NUM_THREADS``, then
    :func:`default_thread_count`; a count above the cores the process may use
    is limited to them (``bvae: warning: …`` names the variable), so that
    OpenMP never aborts the process allocating for it (R3-12). The choice is exported as
    ``OMP_NUM_THREADS`` (read by torch when it is first imported) and applied
    to torch directly if it is already imported.
    """
    env = os.environ if environ is None else environ
    with warnings.catch_warnings(record=True) as caught:  # a count above the cores: limited, said in one line
        warnings.simplefilter("always", ThreadCountWarning)
        chosen = environment_thread_count(env)
    for warning in caught:
        print(f"bvae: warning: {warning.message}", file=sys.stderr)
    count = default_thread_count() if chosen is None else chosen
    env["OMP_NUM_THREADS"] = str(count)
    if environ is None and "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(count)
    return count


@contextlib.contextmanager
def _terminate_cleanly() -> Iterator[None]:
    """Turn SIGTERM into an exception while a command runs (main thread only), then restore the handler."""
    def on_term(signum: int, frame: object) -> None:
        raise Terminated

    try:
        previous = signal.signal(signal.SIGTERM, on_term)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _one_line_warning(command: str) -> object:
    """A ``warnings.showwarning`` that prints ``bvae COMMAND: warning: MESSAGE`` (no source line)."""
    def show(message: Warning | str, category: type[Warning], *args: object, **kwargs: object) -> None:
        print(f"bvae {command}: warning: {message}", file=sys.stderr)

    return show


def _silence_stdout() -> None:
    """After a broken pipe: point stdout at /dev/null so the interpreter's final flush stays quiet."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser of ``bvae``."""
    parser = argparse.ArgumentParser(
        prog="bvae",
        description="Compress measured BRDFs (MERL format) into a tiny, editable β-VAE latent code.",
    )
    parser.add_argument("--version", action="version", version=f"brdfcodec {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    subparsers.required = True
    for module in (
        compress_command,
        decompress_command,
        info_command,
        extract_command,
        edit_command,
        render_command,
        analytic_command,
        dataset_command,
        train_command,
        model_command,
        bench_command,
        studio_command,
    ):
        module.register(subparsers)
    return parser


def _describe(error: BaseException) -> str:
    if isinstance(error, FileExistsError) and error.filename is not None:
        return f"{error.filename}: already exists (use --force to replace it)"
    if isinstance(error, OSError) and error.filename is not None and error.strerror:
        return f"{error.filename}: {error.strerror}"
    return str(error) or type(error).__name__


#: A list of numbers that starts with a minus sign (``-2,0,2``), which argparse would take for an option.
_NEGATIVE_LIST = re.compile(r"^-\.?\d[\d.eE+-]*(,[\d.eE+-]*)+$")


def _join_negative_lists(argv: Sequence[str]) -> list[str]:
    """``--values -2,0,2`` as ``--values=-2,0,2``: argparse reads a value that starts with ``-`` and holds a comma
    as an option and fails with a bare "expected one argument"."""
    out: list[str] = []
    for token in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and _NEGATIVE_LIST.match(token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``bvae`` with ``argv`` (``sys.argv[1:]`` by default) and return the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(_join_negative_lists(sys.argv[1:] if argv is None else argv))
    except SystemExit as stop:  # --help, --version, usage errors
        return int(stop.code or 0)
    if argv is None:  # a real command-line run, not a call from Python: size torch's thread pool
        configure_threads()
    try:
        with _terminate_cleanly(), warnings.catch_warnings():
            warnings.showwarning = _one_line_warning(args.command)
            code = int(args.handler(args))
            sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
            return code
    except KeyboardInterrupt:
        remove_unfinished_outputs()
        print("bvae: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Terminated:
        remove_unfinished_outputs()
        print("bvae: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except UsageError as error:
        print(f"bvae {args.command}: error: {error}", file=sys.stderr)
        return EXIT_USAGE
    except (BrdfcodecError, OSError, ValueError, KeyError) as error:
        if os.environ.get("BVAE_DEBUG") == "1":
            raise
        message = error.args[0] if isinstance(error, KeyError) and error.args else _describe(error)
        print(f"bvae {args.command}: error: {message}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as error:  # noqa: BLE001 - last line of defence, never a traceback
        if os.environ.get("BVAE_DEBUG") == "1":
            raise
        print(
            f"bvae {args.command}: internal error: {type(error).__name__}: {error} "
            "(please report it; set BVAE_DEBUG=1 to see the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL
