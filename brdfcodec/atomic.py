"""Atomic creation of output files: a temporary file beside the target, then a rename."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_output", "check_output_path"]


def check_output_path(path: str | os.PathLike[str], *, overwrite: bool) -> Path:
    """Check that ``path`` may be written.

    Parameters
    ----------
    path : str or os.PathLike
        Target file.
    overwrite : bool
        Whether an existing file may be replaced.

    Returns
    -------
    pathlib.Path
        The target as a path.

    Raises
    ------
    FileExistsError
        The target exists and ``overwrite`` is false.
    IsADirectoryError
        The target is a directory.
    FileNotFoundError
        The target's folder does not exist.
    """
    target = Path(path)
    if target.is_dir():
        raise IsADirectoryError(f"{target}: is a directory, expected a file name to write")
    if target.exists() and not overwrite:
        raise FileExistsError(f"{target}: already exists (pass overwrite=True, or --force, to replace it)")
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{target}: folder {parent} does not exist")
    return target


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path that becomes ``path`` only if the block succeeds.

    The temporary file lives in the target's folder, so the final
    :func:`os.replace` is atomic on POSIX and Windows. On any exception the
    temporary file is removed and the target is left untouched.

    Parameters
    ----------
    path : str or os.PathLike
        Final location of the file.
    overwrite : bool, default False
        Whether an existing file at ``path`` may be replaced.

    Yields
    ------
    pathlib.Path
        Where the caller writes the content.
    """
    target = check_output_path(path, overwrite=overwrite)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_current_umask())
        if target.exists() and not overwrite:  # appeared while we were writing
            raise FileExistsError(f"{target}: already exists (pass overwrite=True, or --force, to replace it)")
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise
