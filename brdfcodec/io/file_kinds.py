"""What a file is, from its first bytes: for messages that say what was given and what was expected.

A reader that finds the wrong content (a MERL reader given an HDF5 file, say)
names the file's actual kind instead of reporting its first bytes as numbers.
The table holds the kinds a brdfcodec user is likely to hand over by
mistake; it reads at most :data:`SNIFF_BYTES` bytes and decides nothing
about the file's validity.
"""

from __future__ import annotations

import os

__all__ = ["SNIFF_BYTES", "describe_file_kind", "sniff_file_kind"]

#: Bytes :func:`sniff_file_kind` needs at most.
SNIFF_BYTES = 12

#: (leading bytes, what a file starting with them is). The ``.bvae`` magic is
#: ``brdfcodec.format.container.MAGIC`` (this layer cannot import it; a test pins the two equal).
_MAGICS: tuple[tuple[bytes, str], ...] = (
    (b"\x89HDF\r\n\x1a\n", "an HDF5 file (a brdfcodec dataset .h5, or an NBRDF fit's NAME.h5 weights)"),
    (b"\x89BVAE\r\n\x1a", "a .bvae file (compressed materials; decode it with bvae decompress)"),
    (b"PK\x03\x04", "a zip archive (an NBRDF fit archive such as merl-nbrdf-90.zip?)"),
    (b"PK\x05\x06", "an empty zip archive"),
    (b"tensor_file\x00", "an RGL .bsdf tensor file"),
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"\x76\x2f\x31\x01", "an OpenEXR image"),
    (b"\x93NUMPY", "a NumPy .npy array"),
    (b"\x1f\x8b", "a gzip-compressed file (decompress it first)"),
)


def sniff_file_kind(head: bytes) -> str | None:
    """What a file starting with ``head`` is, as a noun phrase (``"an HDF5 file (…)"``), or None if unknown.

    Parameters
    ----------
    head : bytes
        The file's first bytes (:data:`SNIFF_BYTES` suffice; fewer may leave it unknown).

    Returns
    -------
    str or None
        A phrase such as ``"a zip archive (…)"``; ``"an empty file"`` for no bytes; ``"a text file
        (JSON?…)"`` for text starting with ``{`` or ``[``, ``"a text file"`` for other printable UTF-8;
        None when the bytes match no known kind.
    """
    if not head:
        return "an empty file"
    for magic, kind in _MAGICS:
        if head.startswith(magic):
            return kind
    try:
        decoded = head.decode("utf-8")
    except UnicodeDecodeError:  # binary, or a multi-byte character cut at the end: not worth telling apart
        return None
    if not all(c.isprintable() or c in "\t\r\n" or c == "\ufeff" for c in decoded):
        return None  # binary bytes, even where the first one happens to be '{' or '['
    if decoded.lstrip(" \t\r\n\ufeff")[:1] in ("{", "["):
        return "a text file (JSON?; an NBRDF fit's NAME.json describes the network, its weights are NAME.h5)"
    return "a text file"


def describe_file_kind(path: str | os.PathLike[str]) -> str | None:
    """:func:`sniff_file_kind` of a file's first bytes; None when unknown or unreadable."""
    try:
        with open(path, "rb") as stream:
            return sniff_file_kind(stream.read(SNIFF_BYTES))
    except OSError:
        return None
