"""Finding a libLLVM that Dr.Jit's LLVM backend (Mitsuba's ``llvm_*`` variants) can use.

Dr.Jit loads libLLVM at run time from ``DRJIT_LIBLLVM_PATH`` or its own
search. Not every version works: libLLVM 15 is found but fails at code
generation ("Cannot select: fminimum"), 14 and older are not accepted. This
module picks a usable one — the environment variable if set, else the newest
of the common system paths and ``ldconfig -p`` at version 16 or later — and
sets ``DRJIT_LIBLLVM_PATH`` before Dr.Jit initialises its LLVM backend.
On Debian or Ubuntu, ``apt-get install libllvm19`` provides one.
"""

from __future__ import annotations

import glob
import os
import re
import subprocess
import warnings
from pathlib import Path

__all__ = ["MIN_LLVM_VERSION", "candidate_libllvm_paths", "configure_libllvm", "find_libllvm", "libllvm_version"]

#: Oldest libLLVM major version known to work with Mitsuba 3.9's LLVM variants.
MIN_LLVM_VERSION = 16

_SEARCH_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
)
_INSTALL_HINT = (
    "install a libLLVM of version 16 or later (Debian/Ubuntu: apt-get install libllvm19) "
    "or point DRJIT_LIBLLVM_PATH at one"
)


def libllvm_version(path: str | os.PathLike[str]) -> int | None:
    """Major version of a libLLVM file, read from its name (``libLLVM-19.so``, ``libLLVM.so.19.1``), or None."""
    name = Path(path).name
    match = re.search(r"libLLVM[-.](?:so\.)?(\d+)", name)
    return int(match.group(1)) if match else None


def candidate_libllvm_paths() -> list[Path]:
    """Every libLLVM file found on the common system paths and by ``ldconfig -p``, newest version first."""
    found: set[Path] = set()
    for pattern in _SEARCH_GLOBS:
        found.update(Path(p) for p in glob.glob(pattern))
    try:
        listing = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True, timeout=5, check=False).stdout
    except (OSError, subprocess.SubprocessError):
        listing = ""
    for line in listing.splitlines():
        if "libLLVM" in line and "=>" in line:
            found.add(Path(line.split("=>", 1)[1].strip()))
    usable = [p for p in found if p.is_file() and libllvm_version(p) is not None]
    return sorted(usable, key=lambda p: (libllvm_version(p) or 0, len(p.name)), reverse=True)


def find_libllvm() -> Path | None:
    """A usable libLLVM: ``$DRJIT_LIBLLVM_PATH`` if set and present, else the newest found at version ≥ 16.

    Returns
    -------
    pathlib.Path or None
        None when none is found.
    """
    configured = os.environ.get("DRJIT_LIBLLVM_PATH")
    if configured and Path(configured).is_file():
        return Path(configured)
    for path in candidate_libllvm_paths():
        version = libllvm_version(path)
        if version is not None and version >= MIN_LLVM_VERSION:
            return path
    return None


def configure_libllvm(*, warn: bool = False) -> Path | None:
    """Set ``DRJIT_LIBLLVM_PATH`` to a usable libLLVM (before Dr.Jit's LLVM backend starts).

    Parameters
    ----------
    warn : bool, default False
        Warn, saying what to install, when none is found.

    Returns
    -------
    pathlib.Path or None
        The library used, or None when none is usable (LLVM variants will fail).
    """
    path = find_libllvm()
    if path is None:
        if warn:
            message = f"no usable libLLVM for Mitsuba's LLVM variants: {_INSTALL_HINT}"
            warnings.warn(message, RuntimeWarning, stacklevel=2)
        return None
    os.environ["DRJIT_LIBLLVM_PATH"] = str(path)
    return path
