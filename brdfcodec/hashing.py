"""SHA-256 of files: how MERL files are recognised and how models and ``.bvae`` files name a decoder."""

from __future__ import annotations

import hashlib
import os

__all__ = ["sha256_of_file"]


def sha256_of_file(path: str | os.PathLike[str]) -> str:
    """SHA-256 (lower-case hex) of a file's bytes, read in chunks.

    Raises
    ------
    FileNotFoundError, IsADirectoryError, PermissionError
        As :func:`open` does, naming the path.
    """
    with open(path, "rb") as stream:
        return hashlib.file_digest(stream, "sha256").hexdigest()
