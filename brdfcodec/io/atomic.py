"""Atomic creation of output files and folders: a temporary file or folder beside the target, then a rename."""

from __future__ import annotations

import contextlib
import errno
import ctypes
import os
import secrets
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["TEMPORARY_PREFIX", "atomic_folder", "atomic_output", "check_output_path", "remove_unfinished_outputs"]

#: Start of the name of every temporary file :func:`atomic_output` makes (``.bvae-XXXXXXXX.part``, beside the target).
TEMPORARY_PREFIX = ".bvae-"
#: Temporary files of :func:`atomic_output` and folders of :func:`atomic_folder` blocks not yet published or
#: removed (paths as given by mkstemp and mkdtemp).
_UNFINISHED: set[str] = set()


def remove_unfinished_outputs() -> list[str]:
    """Remove the temporary files and folders of every :func:`atomic_output` and :func:`atomic_folder` still open;
    return their paths.

    For a process that is being interrupted or terminated: an exception normally removes a block's temporary
    file itself, but one raised between two steps of the context manager's own machinery (entering or leaving
    the block) can bypass that, and the process may exit before the generator is finalised. The ``bvae`` CLI
    calls this when it is interrupted or terminated.
    """
    removed = []
    for name in sorted(_UNFINISHED):
        with contextlib.suppress(FileNotFoundError):
            if os.path.isdir(name) and not os.path.islink(name):
                shutil.rmtree(name)
            else:
                os.unlink(name)
            removed.append(name)
        _UNFINISHED.discard(name)
    return removed


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
        raise FileExistsError(
            errno.EEXIST, "already exists (pass overwrite=True to replace it)", str(target)
        )
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{target}: folder {parent} does not exist")
    return target


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _publish(tmp: Path, target: Path, *, overwrite: bool) -> None:
    """Move the finished temporary file to ``target``; without ``overwrite``, atomically only if absent."""
    if overwrite:
        os.replace(tmp, target)
        return
    try:
        os.link(tmp, target)  # fails if target exists: create-if-absent, no window between check and rename
    except FileExistsError:
        raise FileExistsError(
            errno.EEXIST, "already exists (pass overwrite=True to replace it)", str(target)
        ) from None
    except OSError:  # no hard links here (some network and FAT file systems): reserve the name exclusively
        try:
            fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            raise FileExistsError(
                errno.EEXIST, "already exists (pass overwrite=True to replace it)", str(target)
            ) from None
        os.close(fd)
        os.replace(tmp, target)
        return
    tmp.unlink()


def _name_target(error: OSError, tmp: Path, target: Path) -> None:
    """Errors about the temporary file name the output the caller asked for instead."""
    if error.filename is not None and os.fspath(error.filename) == os.fspath(tmp):
        error.filename = os.fspath(target)


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path that becomes ``path`` only if the block succeeds.

    The temporary file (``.bvae-XXXXXXXX.part``, a short name whatever the
    target's) lives in the target's folder, so the final rename is
    atomic on POSIX and Windows. Without ``overwrite`` the file appears only
    if no file of that name exists at that moment (a hard link, which fails
    on an existing name), so two writers racing for one name cannot both
    succeed. On any exception (``KeyboardInterrupt`` and the ``bvae`` CLI's
    SIGTERM included) the temporary file is removed and the target is left
    untouched; errors about the temporary file name ``path``.

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

    Raises
    ------
    FileExistsError
        ``path`` exists (before or after the block) and ``overwrite`` is false.
    """
    target = check_output_path(path, overwrite=overwrite)
    try:
        # A short fixed name (19 bytes), not one made from the target's: a target whose name is as long as the
        # file system allows must still have a temporary file beside it (issue 49, R3-10).
        fd, tmp_name = tempfile.mkstemp(prefix=TEMPORARY_PREFIX, suffix=".part", dir=target.parent)
    except OSError as error:
        raise type(error)(error.errno, error.strerror, os.fspath(target)) from None
    _UNFINISHED.add(tmp_name)
    # From here on the temporary file exists: every step, even closing it, runs where an exception (a SIGTERM
    # turned into one by the CLI can arrive between any two bytecodes) removes it.
    try:
        os.close(fd)
        tmp = Path(tmp_name)
        yield tmp
        os.chmod(tmp, 0o666 & ~_current_umask())
        _publish(tmp, target, overwrite=overwrite)
    except BaseException as error:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        if isinstance(error, OSError):
            _name_target(error, Path(tmp_name), target)
        raise
    finally:
        _UNFINISHED.discard(tmp_name)


_RENAME_EXCHANGE = 2  # renameat2's flag (Linux ≥ 3.15): swap two existing paths in one step
_AT_FDCWD = -100


def _exchange(first: Path, second: Path) -> bool:
    """Swap two existing folders in one atomic step where the system can (Linux's ``renameat2``); False where it
    cannot (another system, an old kernel or C library, a file system without the flag)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    renameat2.restype = ctypes.c_int
    if renameat2(_AT_FDCWD, os.fsencode(first), _AT_FDCWD, os.fsencode(second), _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise OSError(code, os.strerror(code), os.fspath(second))


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike[str], *, replace: bool = False) -> Iterator[Path]:
    """Yield a temporary folder that becomes the folder ``path`` only if the block succeeds.

    The temporary folder (``.bvae-XXXXXXXX.part``) lives beside the target. Without ``replace`` it starts empty
    and is renamed to ``path``, which must not exist. With ``replace`` it starts as a copy of the existing folder
    ``path`` (a shallow tree of regular files, as a model folder is) and takes its place in one step where the
    system can swap two folders (Linux); elsewhere by two renames, the old folder kept beside under a temporary
    name in between. Either way a reader sees the old folder or the new one whole, never a mix of the two (a
    manifest naming the hash of a file that is not yet there, say). On any exception (``KeyboardInterrupt`` and
    the ``bvae`` CLI's SIGTERM included) the temporary folder is removed and ``path`` is left untouched.

    Parameters
    ----------
    path : str or os.PathLike
        The folder to create (``replace=False``) or to replace (``replace=True``; through a symbolic link, the
        folder it names).
    replace : bool, default False
        Replace an existing folder's contents as a whole.

    Yields
    ------
    pathlib.Path
        Where the caller writes the folder's files.

    Raises
    ------
    FileExistsError
        ``path`` exists (before or after the block) and ``replace`` is false.
    NotADirectoryError
        ``replace`` is true and ``path`` is not a folder.
    FileNotFoundError
        The target's parent folder does not exist.
    """
    target = Path(path)
    if replace and not target.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "is not a folder to replace", os.fspath(target))
    if replace:  # a link to a folder: the folder it names is replaced, the link kept
        target = target.resolve()
    if not replace and (target.exists() or target.is_symlink()):
        raise FileExistsError(errno.EEXIST, "already exists", os.fspath(target))
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{target}: folder {parent} does not exist")
    staging = Path(tempfile.mkdtemp(prefix=TEMPORARY_PREFIX, suffix=".part", dir=parent))
    _UNFINISHED.add(os.fspath(staging))
    try:
        if replace:
            shutil.copytree(target, staging, dirs_exist_ok=True)  # the folder's mode too (copystat)
        else:
            os.chmod(staging, 0o777 & ~_current_umask())
        yield staging
        if not replace:
            if target.exists() or target.is_symlink():  # renaming onto an empty folder would succeed silently
                raise FileExistsError(errno.EEXIST, "already exists", os.fspath(target))
            os.rename(staging, target)
        elif _exchange(staging, target):
            shutil.rmtree(staging, ignore_errors=True)  # now the old folder
        else:
            retired = parent / f"{TEMPORARY_PREFIX}{secrets.token_hex(4)}.old"
            os.rename(target, retired)
            try:
                os.rename(staging, target)
            except BaseException:
                os.rename(retired, target)
                raise
            shutil.rmtree(retired, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    finally:
        _UNFINISHED.discard(os.fspath(staging))
