"""SHA-256 of files: how MERL files are recognised and how models and ``.bvae`` files name a decoder."""

from __future__ import annotations

import hashlib
import os

__all__ = [
    "SHORT_REFERENCE_BYTES",
    "is_reference_hex",
    "is_sha256_hex",
    "read_with_sha256",
    "refers_to",
    "sha256_of_file",
]

#: Bytes of a short reference (``spec/bvae-format.md`` §3.1, format 2.6): the first 8 bytes of a SHA-256, written
#: as 16 hex digits where a file's decoder or shared basis is named by one.
SHORT_REFERENCE_BYTES = 8


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


def is_reference_hex(value: object) -> bool:
    """Whether ``value`` names a file by its SHA-256 as a ``.bvae`` file may: all 64 lower-case hex digits, or the
    first 16 of them (a short reference, format 2.6)."""
    return isinstance(value, str) and len(value) in (64, 2 * SHORT_REFERENCE_BYTES) and all(
        c in "0123456789abcdef" for c in value)


def refers_to(reference: str, sha256: str) -> bool:
    """Whether a file's ``reference`` (64 hex digits, or a short reference's 16) names the file of this SHA-256.

    Parameters
    ----------
    reference : str
        As a ``.bvae`` header states it (:func:`is_reference_hex`).
    sha256 : str
        The full SHA-256 of a decoder or basis file, 64 lower-case hex digits.
    """
    if len(reference) == 2 * SHORT_REFERENCE_BYTES:
        return len(sha256) == 64 and sha256.startswith(reference)
    return reference == sha256
