"""Entry point of ``bvae``: argument parsing and error reporting.

Each sub-command lives in its own module with ``register(subparsers)``; its
handler returns an exit code. Errors about data or files are printed as one
line naming the file and the problem, with exit code 1; usage errors exit
with 2; nothing prints a traceback unless ``BVAE_DEBUG=1`` is set.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

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
from brdfcodec.errors import BrdfcodecError
from brdfcodec.version import __version__

__all__ = ["build_parser", "main"]

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130


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
    if isinstance(error, OSError) and error.filename is not None and error.strerror:
        return f"{error.filename}: {error.strerror}"
    return str(error) or type(error).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``bvae`` with ``argv`` (``sys.argv[1:]`` by default) and return the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as stop:  # --help, --version, usage errors
        return int(stop.code or 0)
    try:
        return int(args.handler(args))
    except KeyboardInterrupt:
        print("bvae: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
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
