"""Reading a file of a folder that came from elsewhere (a model folder): only a regular file inside the folder,
only up to a size limit.

A folder someone else made can hold a link to ``/dev/zero`` (an endless read), to ``/etc/passwd`` (a file
outside it), or a FIFO (a read that never returns). :func:`read_folder_file` refuses each before reading a
byte of it: the file, links followed, must lie inside the folder, links followed too, and be a regular file
of at most ``limit`` bytes.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from pathlib import Path

from brdfcodec.errors import FileFormatError

__all__ = ["read_folder_file"]


def read_folder_file(
    folder: str | os.PathLike[str], name: str, *, limit: int,
    error: Callable[[Path, str], Exception] = FileFormatError,
) -> bytes:
    """The bytes of ``folder/name`` if it is a regular file inside ``folder`` of at most ``limit`` bytes.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder (may itself be reached through links).
    name : str
        File name inside it.
    limit : int
        Largest accepted size, bytes (≥ 0).
    error : callable
        Makes the error raised for a file that is refused from its path and the problem
        (``error(path, problem)``; :class:`~brdfcodec.errors.FileFormatError` by default).

    Returns
    -------
    bytes
        The whole file, read once (what a caller hashes is exactly what it loads).

    Raises
    ------
    FileFormatError (or ``error``)
        The file is missing, a link to outside the folder, not a regular file (a FIFO, a device, a
        folder), or larger than ``limit``.
    """
    path = Path(folder) / name
    try:
        base = Path(folder).resolve(strict=True)
        real = path.resolve(strict=True)
    except FileNotFoundError:
        raise error(path, "no such file") from None
    except (OSError, RuntimeError) as problem:  # a link loop, a folder that cannot be searched
        raise error(path, f"cannot be resolved ({problem})") from None
    if not real.is_relative_to(base):
        raise error(path, f"links to {real}, outside its folder; only files inside the folder are read")
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        descriptor = os.open(real, flags)  # non-blocking: opening a FIFO returns at once, and is refused below
    except OSError as problem:
        raise error(path, f"cannot be opened ({problem.strerror or problem})") from None
    with os.fdopen(descriptor, "rb") as stream:
        info = os.fstat(stream.fileno())
        if not stat.S_ISREG(info.st_mode):
            raise error(path, "is not a regular file (a FIFO, device or folder); only regular files are read")
        if info.st_size > limit:
            raise error(path, f"is {info.st_size:,} bytes, more than the {limit:,} accepted")
        data = stream.read(limit + 1)
    if len(data) > limit:  # grew while read
        raise error(path, f"is more than the {limit:,} bytes accepted")
    return bytes(data)
