"""SHA-256 of files: how MERL files are recognised and how models and ``.bvae`` files name a decoder."""

from __future__ import annotations

import hashlib
import os

__all__ = ["is_sha256_hex", "read_with_sha256", "sha256_of_file"]


def sha256_of_file(path: str | os.PathLike[str]) -> str:
    """SHA-256 (lower-case hex) of a file's bytes, read in chunks.

    Raises
    ------
    FileNotFoundError, IsADirectoryError, PermissionError
        As :func:`open` does, naming the path.
    """
    with open(path, "rb") as stream:
        return hashlib.file_digest(stream, "sha256").hexdigest()


def read_with_sha256(path: str | os.PathLike[str]) -> tuple[bytes, str]:
    """A file's bytes and their SHA-256, from one read: what is verified is exactly what gets loaded."""
    with open(path, "rb") as stream:
        data = stream.read()
    return data, hashlib.sha256(data).hexdigest()


def is_sha256_hex(value: object) -> bool:
    """Whether ``value`` is a SHA-256 written as 64 lower-case hex digits (how files and records name one)."""
    return isinstance(value, str) and len(value) == 64 and all(c in "0123456789abcdef" for c in value)
