"""Recognising the 100 genuine MERL files by their SHA-256.

The published checksums ship with the package (``brdfcodec/data/merl-sha256.txt``,
``sha256sum`` format). A file whose bytes hash to one of them *is* that MERL
measurement; anything else (the NBRDF proxy, an edited or re-encoded table)
is not, whatever its name.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from importlib import resources
from types import MappingProxyType

from brdfcodec.io.hashing import sha256_of_file  # re-exported: its former home

__all__ = ["genuine_merl_checksums", "genuine_merl_name", "sha256_of_file"]


@functools.cache
def genuine_merl_checksums() -> Mapping[str, str]:
    """Published SHA-256 of each genuine MERL file.

    Returns
    -------
    Mapping[str, str]
        Lower-case hex digest to material name (file name without ``.binary``).
    """
    text = resources.files("brdfcodec").joinpath("data/merl-sha256.txt").read_text(encoding="utf-8")
    table: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            continue
        digest, file_name = line.split(maxsplit=1)
        table[digest.lower()] = file_name.strip().lstrip("*").removesuffix(".binary")
    return MappingProxyType(table)


def genuine_merl_name(sha256: str) -> str | None:
    """Name of the genuine MERL material with this checksum, or None.

    Parameters
    ----------
    sha256 : str
        Hex digest of a file's bytes.
    """
    return genuine_merl_checksums().get(sha256.lower())
