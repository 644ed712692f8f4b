"""Atomic creation of output files and folders: a temporary file or folder beside the target, then a rename."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import secrets
import shutil
import stat
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
    raise OSError(code, f"cannot swap the rewritten folder in ({os.strerror(code)})", os.fspath(second))


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike[str], *, replace: bool = False) -> Iterator[Path]:
    """Yield a temporary folder that becomes the folder ``path`` only if the block succeeds.

    The temporary folder (``.bvae-XXXXXXXX.part``) lives beside the target, so its parent must be writable. Without
    ``replace`` it starts empty and is renamed to ``path``, which must not exist. With ``replace`` it starts as a
    copy of the existing folder ``path`` (links inside it copied as links; the folder's mode kept, the copy
    writable by its owner while the block runs) and takes its place: in one step where the system can swap two
    folders (Linux's ``renameat2``), so that a reader that opens the folder sees the old folder or the new one, never
    a mix of the two (a manifest naming the hash of a weight file not yet there, say); elsewhere by two renames,
    between which ``path`` is briefly absent (the old folder is put back if the second fails). An exception in the
    block or before the swap (``KeyboardInterrupt`` and the ``bvae`` CLI's SIGTERM included) removes the temporary
    folder and leaves ``path`` as it was; one during the removal of the old folder after the swap leaves the new
    folder in place.

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
    OSError
        The temporary folder cannot be made beside ``path`` (a read-only parent), or the two folders cannot be
        swapped (``path`` a mount point, say); the error names ``path``.
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
    try:
        staging = Path(tempfile.mkdtemp(prefix=TEMPORARY_PREFIX, suffix=".part", dir=parent))
    except OSError as error:
        raise type(error)(error.errno, f"cannot make a folder beside it ({error.strerror})",
                          os.fspath(target)) from None
    _UNFINISHED.add(os.fspath(staging))
    try:
        mode = 0o777 & ~_current_umask()
        if replace:
            mode = stat.S_IMODE(target.stat().st_mode)
            shutil.copytree(target, staging, symlinks=True, dirs_exist_ok=True)
        os.chmod(staging, mode | stat.S_IRWXU)  # the block may write whatever the folder's own mode
        yield staging
        os.chmod(staging, mode)
        if not replace:
            if target.exists() or target.is_symlink():  # renaming onto an empty folder would succeed silently
                raise FileExistsError(errno.EEXIST, "already exists", os.fspath(target))
            os.rename(staging, target)
        elif not _exchange(staging, target):
            _replace_by_two_renames(staging, target)
    except BaseException:
        _remove_folder(staging)
        raise
    finally:
        _UNFINISHED.discard(os.fspath(staging))
    _remove_folder(staging)  # after a swap: the old folder


def _replace_by_two_renames(staging: Path, target: Path) -> None:
    """``target`` moved aside, ``staging`` renamed to it, the old folder put back if that fails or is interrupted;
    the old folder is left at ``staging``'s name, for the caller to remove."""
    retired = target.parent / f"{TEMPORARY_PREFIX}{secrets.token_hex(4)}.old"
    try:
        os.rename(target, retired)
        os.rename(staging, target)
    except BaseException:
        if retired.exists() and not target.exists():
            os.rename(retired, target)
        raise
    os.rename(retired, staging)


def _remove_folder(folder: Path) -> None:
    """Remove a temporary folder, read-only ones included (a copy keeps its folders' modes)."""
    if not folder.is_dir() or folder.is_symlink():
        return
    for root, _, _ in os.walk(folder):
        with contextlib.suppress(OSError):
            os.chmod(root, stat.S_IRWXU)
    shutil.rmtree(folder, ignore_errors=True)
