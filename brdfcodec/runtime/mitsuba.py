"""Choosing a Mitsuba 3 variant, and finding a libLLVM that Dr.Jit's LLVM backend can use.

Mitsuba's vectorised CPU variants (``llvm_ad_rgb``, ...) compile kernels with
libLLVM, which Dr.Jit loads at run time from ``DRJIT_LIBLLVM_PATH`` or its own
default name. Not every installed libLLVM works: version 15 loads but fails
at code generation ("Cannot select: fminimum"), and 14 and older are refused.
:func:`find_libllvm` looks, in order, at

1. ``$DRJIT_LIBLLVM_PATH`` when it is set (used as it is, even if its version
   is unknown; a known-bad version is refused with the reason);
2. the newest usable ``libLLVM`` among the common system folders
   (``/usr/lib/x86_64-linux-gnu``, ``/usr/lib/llvm-*/lib``, Homebrew, ...)
   and what ``ldconfig -p`` lists.

:func:`set_variant` sets ``DRJIT_LIBLLVM_PATH`` to what it found *before*
Mitsuba's LLVM variants are first used, then sets the first variant that
works, falling back to ``scalar_rgb`` with a warning. On Debian and Ubuntu,
``apt-get install libllvm19`` provides a working library.

The functions here import nothing heavy until they are called; they are
shared by the BSDF plug-in (:mod:`brdfcodec.render.mitsuba_bsdf`) and by any code
that renders or tabulates materials with Mitsuba.
"""

from __future__ import annotations

import glob
import os
import re
import shutil
import subprocess
import sys
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "INSTALL_HINT",
    "KNOWN_BAD_LLVM_MAJORS",
    "MIN_LLVM_MAJOR",
    "LibLLVM",
    "LibLLVMNotFoundError",
    "MitsubaVariantWarning",
    "find_libllvm",
    "libllvm_candidates",
    "set_variant",
]

#: Oldest libLLVM major version Dr.Jit 1.x accepts here (14 is refused by Dr.Jit).
MIN_LLVM_MAJOR = 15
#: Majors that load but fail: 15 fails at code generation ("Cannot select: fminimum").
KNOWN_BAD_LLVM_MAJORS = frozenset({15})
#: What to tell a user who has no usable libLLVM.
INSTALL_HINT = (
    "install a recent libLLVM (Debian/Ubuntu: `apt-get install libllvm19`; macOS: `brew install llvm`) "
    "or point DRJIT_LIBLLVM_PATH at one (libLLVM 16 or newer)"
)

_SEARCH_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
)
_VERSION_PATTERNS = (
    re.compile(r"libLLVM-(\d+)(?:\.\d+)*(?:git)?\.(?:so|dylib)"),  # libLLVM-19.so, libLLVM-14.0.6.so.1
    re.compile(r"libLLVM\.so\.(\d+)"),  # libLLVM.so.19.1
    re.compile(r"libLLVM\.(\d+)(?:\.\d+)*\.dylib"),
)
_FOLDER_PATTERN = re.compile(r"llvm[-@]?(\d+)")


class LibLLVMNotFoundError(RuntimeError):
    """No libLLVM that Mitsuba's LLVM variants can use was found (the message says what to install)."""


class MitsubaVariantWarning(UserWarning):
    """A requested Mitsuba variant is unavailable and another one was set."""


@dataclass(frozen=True)
class LibLLVM:
    """A libLLVM shared library found on this machine.

    Attributes
    ----------
    path : Path
        The library file.
    major : int or None
        Its major version, read from the file or folder name (None: unknown).
    source : str
        Where it was found: ``"DRJIT_LIBLLVM_PATH"``, ``"search"`` or ``"ldconfig"``.
    """

    path: Path
    major: int | None
    source: str

    @property
    def usable(self) -> bool:
        """Whether its version is one known to work (unknown versions are tried only when named explicitly)."""
        return self.major is not None and self.major >= MIN_LLVM_MAJOR and self.major not in KNOWN_BAD_LLVM_MAJORS


def llvm_major(path: str | os.PathLike[str]) -> int | None:
    """Major version of a libLLVM from its file name (or its ``llvm-N`` folder), None when it does not say."""
    name = Path(path).name
    for pattern in _VERSION_PATTERNS:
        match = pattern.fullmatch(name) or pattern.match(name)
        if match:
            return int(match.group(1))
    for part in reversed(Path(path).parts[:-1]):
        match = _FOLDER_PATTERN.search(part)
        if match:
            return int(match.group(1))
    return None


def _ldconfig_paths() -> list[str]:
    ldconfig = shutil.which("ldconfig") or ("/sbin/ldconfig" if os.path.exists("/sbin/ldconfig") else None)
    if ldconfig is None or not sys.platform.startswith("linux"):
        return []
    try:
        listing = subprocess.run([ldconfig, "-p"], capture_output=True, text=True, timeout=10, check=False).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    return [line.rsplit("=>", 1)[1].strip() for line in listing.splitlines() if "libLLVM" in line and "=>" in line]


def libllvm_candidates(extra_globs: Iterable[str] = ()) -> list[LibLLVM]:
    """Every libLLVM file in the common folders and in ``ldconfig -p``, newest major first.

    Parameters
    ----------
    extra_globs : iterable of str
        More glob patterns to search (tests use them).

    Returns
    -------
    list of LibLLVM
        Existing files, each real file once, sorted by major version
        (newest first; unknown versions last).
    """
    found: dict[str, LibLLVM] = {}
    for source, paths in (
        ("search", [p for pattern in (*extra_globs, *_SEARCH_GLOBS) for p in sorted(glob.glob(pattern))]),
        ("ldconfig", _ldconfig_paths()),
    ):
        for path in paths:
            if not os.path.isfile(path):
                continue
            real = os.path.realpath(path)
            major = llvm_major(path) or llvm_major(real)
            if real not in found or (found[real].major is None and major is not None):
                found[real] = LibLLVM(Path(path), major, source)
    return sorted(found.values(), key=lambda lib: (-(lib.major or -1), str(lib.path)))


def find_libllvm(*, extra_globs: Iterable[str] = (), environ: dict[str, str] | None = None) -> LibLLVM:
    """The libLLVM Mitsuba's LLVM variants should load.

    Parameters
    ----------
    extra_globs : iterable of str
        More glob patterns, searched before the common folders.
    environ : dict, optional
        Environment to read ``DRJIT_LIBLLVM_PATH`` from (default: ``os.environ``).

    Returns
    -------
    LibLLVM

    Raises
    ------
    LibLLVMNotFoundError
        ``DRJIT_LIBLLVM_PATH`` names a missing file or a known-bad version, or
        no usable library was found; the message lists what was seen and what
        to install.
    """
    env = os.environ if environ is None else environ
    named = env.get("DRJIT_LIBLLVM_PATH")
    if named:
        major = llvm_major(named) or llvm_major(os.path.realpath(named))
        if not os.path.isfile(named):
            raise LibLLVMNotFoundError(f"DRJIT_LIBLLVM_PATH={named}: no such file; {INSTALL_HINT}")
        if major is not None and (major < MIN_LLVM_MAJOR or major in KNOWN_BAD_LLVM_MAJORS):
            raise LibLLVMNotFoundError(f"DRJIT_LIBLLVM_PATH={named}: libLLVM {major} does not work with "
                                       f"Mitsuba's LLVM variants; {INSTALL_HINT}")
        return LibLLVM(Path(named), major, "DRJIT_LIBLLVM_PATH")
    candidates = libllvm_candidates(extra_globs)
    usable = [lib for lib in candidates if lib.usable]
    if usable:
        return usable[0]
    seen = ", ".join(f"{lib.path} ({lib.major or '?'})" for lib in candidates) or "none"
    raise LibLLVMNotFoundError(f"no usable libLLVM found (seen: {seen}); {INSTALL_HINT}")


def _llvm_problem() -> str | None:
    """Point Dr.Jit at a usable libLLVM (checking a preset DRJIT_LIBLLVM_PATH); None if its backend loads."""
    try:
        os.environ["DRJIT_LIBLLVM_PATH"] = str(find_libllvm().path)
    except LibLLVMNotFoundError as error:
        return str(error)
    import drjit as dr

    if not dr.has_backend(dr.JitBackend.LLVM):
        return f"Dr.Jit could not load {os.environ['DRJIT_LIBLLVM_PATH']} ({INSTALL_HINT})"
    return None


def set_variant(
    preferred: str | Sequence[str] = ("llvm_ad_rgb",),
    *,
    fallback: str | None = "scalar_rgb",
    warn: bool = True,
) -> str:
    """Set the first Mitsuba variant of ``preferred`` that works here, else ``fallback``.

    ``llvm_*`` variants need a usable libLLVM (:func:`find_libllvm`; its path
    is put in ``DRJIT_LIBLLVM_PATH`` before Dr.Jit loads LLVM), ``cuda_*``
    variants a CUDA device.

    Parameters
    ----------
    preferred : str or sequence of str, default ("llvm_ad_rgb",)
        Variants to try, in order.
    fallback : str or None, default "scalar_rgb"
        Variant to set when none of ``preferred`` works (None: raise instead).
    warn : bool, default True
        Emit a :class:`MitsubaVariantWarning` when falling back.

    Returns
    -------
    str
        The variant now set.

    Raises
    ------
    ImportError
        Mitsuba 3 is not installed.
    LibLLVMNotFoundError
        An ``llvm_*`` variant was asked for, no usable libLLVM exists and
        ``fallback`` is None.
    RuntimeError
        No requested variant is available and ``fallback`` is None.
    """
    wanted = [preferred] if isinstance(preferred, str) else list(preferred)
    try:
        import mitsuba as mi
    except ImportError as error:
        raise ImportError("rendering with Mitsuba needs Mitsuba 3: pip install 'brdfcodec[mitsuba]'") from error
    reasons = []
    for variant in wanted:
        if variant not in mi.variants():
            reasons.append(f"{variant}: not built into this Mitsuba ({', '.join(mi.variants())})")
            continue
        problem = _llvm_problem() if variant.startswith("llvm_") else None
        if problem is not None:
            reasons.append(f"{variant}: {problem}")
            continue
        if variant.startswith("cuda_"):
            import drjit as dr

            if not dr.has_backend(dr.JitBackend.CUDA):
                reasons.append(f"{variant}: no CUDA device")
                continue
        try:
            mi.set_variant(variant)
        except Exception as error:  # noqa: BLE001 - Mitsuba raises plain exceptions for backend failures
            reasons.append(f"{variant}: {error}")
            continue
        return variant
    if fallback is None:
        if any("libLLVM" in reason for reason in reasons):
            raise LibLLVMNotFoundError("; ".join(reasons))
        raise RuntimeError("no requested Mitsuba variant is available: " + "; ".join(reasons))
    if warn:
        warnings.warn(f"using Mitsuba's {fallback} variant: " + "; ".join(reasons), MitsubaVariantWarning,
                      stacklevel=2)
    mi.set_variant(fallback)
    return fallback


def current_variant() -> str | None:
    """Mitsuba's current variant, or None (Mitsuba not imported or no variant set)."""
    mi: Any = sys.modules.get("mitsuba")
    return None if mi is None else mi.variant()
