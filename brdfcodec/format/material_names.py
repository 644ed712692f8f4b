"""Material names: what a name may be, and the file a name becomes (``spec/bvae-format.md`` §4.3).

A material name travels from a ``.bvae`` header into file names
(``bvae decompress LIB.bvae -o folder``), URLs and scene descriptions, so a
name is restricted to what is a safe, portable file name on every common
file system: no path separators, no ``.``/``..``, nothing that Windows
refuses, no control characters, no lone surrogates, Unicode NFC, and unique
in its file after case folding (``Gold`` and ``gold`` would be one file on
macOS and Windows). This module is the one place those rules live; it
imports nothing but the standard library.
"""

from __future__ import annotations

import os
import unicodedata
from pathlib import Path

__all__ = [
    "FORBIDDEN_CHARACTERS",
    "MAX_NAME_BYTES",
    "MAX_NAME_LENGTH",
    "check_material_name",
    "file_name_form",
    "material_file_path",
    "name_collision_key",
    "shown_name",
]

#: Most UTF-8 bytes of a name's file-name form (:func:`file_name_form`, ``spec/bvae-format.md`` §4.3): with the
#: longest extension a tool adds (``.binary``, 7 bytes) and a margin, a file name within the 255 bytes that common
#: file systems allow.
MAX_NAME_BYTES = 240
#: Longest material name, in Unicode code points (a name of more has more than :data:`MAX_NAME_BYTES` bytes).
MAX_NAME_LENGTH = MAX_NAME_BYTES
#: Characters a name MUST NOT hold besides control characters: path separators and what Windows refuses.
FORBIDDEN_CHARACTERS = frozenset('/\\:*?"<>|')
_WINDOWS_DEVICES = frozenset(
    ["CON", "PRN", "AUX", "NUL"] + [f"{p}{i}" for p in ("COM", "LPT") for i in [*range(10), *"¹²³"]]
)
#: U+FEFF (a byte-order mark; §3.3 says names are UTF-8 without one) may not start a name.
_BYTE_ORDER_MARK = "\ufeff"


def file_name_form(name: str) -> str:
    """The name as a file name: each format character (category Cf, such as U+202E right-to-left override)
    replaced by ``[U+XXXX]``, so that no file name hides or reorders what it shows (``spec/bvae-format.md`` §4.3).

    Examples
    --------
    >>> file_name_form("gold\u202egnp.exe")
    'gold[U+202E]gnp.exe'
    """
    if name.isascii():
        return name
    return "".join(f"[U+{ord(c):04X}]" if unicodedata.category(c) == "Cf" else c for c in name)


def shown_name(name: str) -> str:
    """The name as shown to a person: every character that is not printable (format characters, white space
    other than U+0020, …) escaped as ``\\uXXXX`` (``spec/bvae-format.md`` §4.3).

    Examples
    --------
    >>> print(shown_name("gold\u202egnp.exe"))
    gold\\u202egnp.exe
    """
    if name.isprintable():
        return name
    return "".join(c if c.isprintable() else (f"\\u{ord(c):04x}" if ord(c) < 0x10000 else f"\\U{ord(c):08x}")
                   for c in name)


def _problem(name: str) -> str | None:
    """Why ``name`` is not a valid material name, or None if it is."""
    if not 1 <= len(name) <= MAX_NAME_LENGTH:
        return f"must be 1 to {MAX_NAME_LENGTH} characters long, has {len(name)}"
    plain_ascii = name.isascii() and name.isprintable()  # the common case: no control character, no surrogate
    if name.startswith(_BYTE_ORDER_MARK):
        return "starts with U+FEFF (a byte-order mark)"
    for char in name if not plain_ascii else FORBIDDEN_CHARACTERS.intersection(name):
        category = unicodedata.category(char)
        if category == "Cs":
            return f"holds a lone surrogate U+{ord(char):04X} (not a Unicode character)"
        if category == "Cc":
            return f"holds the control character U+{ord(char):04X}"
        if char in FORBIDDEN_CHARACTERS:
            return f"holds {char!r} (no path separators or {''.join(sorted(FORBIDDEN_CHARACTERS))})"
    if name.startswith("."):
        return "starts with '.' (no hidden files, no '.' or '..')"
    if name[0].isspace() or name[-1].isspace():
        return "starts or ends with white space"
    if name.endswith("."):
        return "ends with '.'"
    if not plain_ascii and unicodedata.normalize("NFC", name) != name:
        return "is not in Unicode normalisation form NFC"
    if name.split(".", 1)[0].rstrip().upper() in _WINDOWS_DEVICES:
        return "is a reserved device name on Windows (CON, PRN, AUX, NUL, COM0-9, LPT0-9, COM¹²³, LPT¹²³)"
    size = len(file_name_form(name).encode("utf-8"))
    if size > MAX_NAME_BYTES:
        return (f"takes {size} bytes as a file name (UTF-8, format characters written [U+XXXX]), more than "
                f"{MAX_NAME_BYTES}")
    return None


def check_material_name(name: object) -> str:
    """Return ``name`` if it is a valid material name.

    Parameters
    ----------
    name : object
        Candidate name.

    Returns
    -------
    str
        The name, unchanged.

    Raises
    ------
    ValueError
        The name breaks a rule of ``spec/bvae-format.md`` §4.3; the message says which.

    Examples
    --------
    >>> check_material_name("gold-metallic-paint")
    'gold-metallic-paint'
    >>> check_material_name("../up")
    Traceback (most recent call last):
    ...
    ValueError: invalid material name '../up': holds '/' (no path separators or "*/:<>?\\|)
    """
    if not isinstance(name, str):
        raise ValueError(f"a material name must be a string, got {type(name).__name__}")
    problem = _problem(name)
    if problem is not None:
        raise ValueError(f"invalid material name {name!r}: {problem}")
    return name


def name_collision_key(name: str) -> str:
    """The key under which two names count as the same: NFC, the file-name form (:func:`file_name_form`: two names
    that would be one file, such as ``a\u200bb`` and ``a[U+200B]b``, are one name), then Unicode case folding.

    Examples
    --------
    >>> name_collision_key("Gold") == name_collision_key("gold")
    True
    """
    return unicodedata.normalize("NFC", file_name_form(unicodedata.normalize("NFC", name)).casefold())


def material_file_path(folder: str | os.PathLike[str], name: str, suffix: str) -> Path:
    """The file ``folder/NAME.SUFFIX`` for a material, guaranteed to lie directly inside ``folder``; NAME is the
    name's :func:`file_name_form` (format characters written ``[U+XXXX]``).

    Parameters
    ----------
    folder : str or os.PathLike
        Output folder.
    name : str
        Material name; checked with :func:`check_material_name`.
    suffix : str
        File type, with or without the leading dot (``"binary"``, ``".npy"``).

    Returns
    -------
    pathlib.Path
        A path whose parent is ``folder``.

    Raises
    ------
    ValueError
        The name is not a valid material name, or would leave the folder.
    """
    check_material_name(name)
    base = Path(folder)
    path = base / f"{file_name_form(name)}.{suffix.lstrip('.')}"
    # Defence in depth: the rules above already exclude separators, '.' and '..'.
    if path.parent != base or len(path.parts) != len(base.parts) + 1:
        raise ValueError(f"material name {name!r} does not give a file name inside {base}")
    return path
