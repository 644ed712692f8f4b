"""The output types of ``bvae`` commands, checked alike: the file name's extension says what is written.

Every command that writes a file checks ``-o``'s extension against the types
it writes before it reads or computes anything, and refuses another with a
usage error (exit code 2) that names the types it writes: ``bvae analytic
gold -o g.bvae`` does not write a MERL table under a ``.bvae`` name.
Extensions compare without regard to case (``.BVAE`` is ``.bvae``).

A command that can also write a folder (``bvae decompress``) writes one
only when asked: see :func:`is_folder_request`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from brdfcodec.cli.usage import UsageError

__all__ = ["is_folder_request", "require_output_type"]


def require_output_type(path: str | os.PathLike[str], command: str, writes: str, suffixes: Sequence[str]) -> str:
    """The output's extension, lower-cased, when it is one of ``suffixes``; a UsageError naming them otherwise.

    Parameters
    ----------
    path : str or os.PathLike
        The ``-o`` argument.
    command : str
        The sub-command, for the message (``"analytic"``, ``"dataset build"``).
    writes : str
        What the command writes, for the message (``"a MERL table"``).
    suffixes : sequence of str
        The extensions it writes, with their dot (``(".binary",)``).

    Returns
    -------
    str
        The matching extension (``".binary"``).

    Raises
    ------
    UsageError
        Another extension, or none.
    """
    suffix = Path(path).suffix.lower()
    if suffix in suffixes:
        return suffix
    choices = suffixes[0] if len(suffixes) == 1 else f"one of {', '.join(suffixes)}"
    got = f"not {Path(path).suffix}" if suffix else "it has no extension"
    raise UsageError(f"{os.fspath(path)}: bvae {command} writes {writes}: the output name must end in {choices} "
                     f"({got})")


def is_folder_request(text: str) -> bool:
    """Whether an ``-o`` argument asks for a folder: it ends in a path separator (``out/``), names an existing
    folder, or has no extension (``decoded``: no file type is named, as before ``-o out/`` existed)."""
    if text.endswith(("/", os.sep)):
        return True
    path = Path(text)
    return path.is_dir() or not path.suffix
