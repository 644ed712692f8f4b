"""Shared bases on disk: safetensors files named by their SHA-256, checked when loaded, cached per file.

Part of :mod:`brdfcodec.layers.basis`, which gathers the names of its parts.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import numpy.typing as npt

from brdfcodec.errors import BasisError
from brdfcodec.io.hashing import refers_to
from brdfcodec.layers.quantise import _N_ENTRIES, BASIS_FILE, MAX_BASIS_COUNT
from brdfcodec.layers.shared_basis import FactorisedBasis, SharedBasis, _factorised

__all__ = [
    "load_shared_basis",
    "model_basis_lookup",
    "write_factorised_basis",
    "write_shared_basis",
]


def write_shared_basis(
    path: str | os.PathLike[str], components: npt.ArrayLike, entries: npt.ArrayLike
) -> str:
    """Write a basis file atomically and return its SHA-256 (what records and ``model.json`` name it by)."""
    from safetensors.numpy import save_file

    from brdfcodec.io.atomic import atomic_output
    from brdfcodec.io.hashing import sha256_of_file

    tensors = {
        "components": np.ascontiguousarray(components, dtype=np.float16),
        "entries": np.ascontiguousarray(entries, dtype=np.int64),
    }
    _validate(tensors["components"], tensors["entries"], str(path))
    with atomic_output(Path(path), overwrite=True) as tmp:
        save_file(tensors, str(tmp))
    return sha256_of_file(path)

#: Largest basis file read, bytes (the shipped one is 17 MB).
MAX_BASIS_FILE_BYTES = 512 << 20


def load_shared_basis(path: str | os.PathLike[str], expected_sha256: str) -> SharedBasis:
    """Read a basis file after checking its SHA-256.

    Raises
    ------
    BasisError
        The file's hash is not ``expected_sha256``, or its tensors are malformed.
    """
    import hashlib

    from safetensors import SafetensorError
    from safetensors.numpy import load

    from brdfcodec.io.folder_files import read_folder_file

    file = Path(path)  # only a regular file inside its folder, of bounded size (spec/model.md §3)
    data = read_folder_file(file.parent, file.name, limit=MAX_BASIS_FILE_BYTES,
                            error=lambda where, problem: BasisError(f"{where}: {problem}"))
    actual = hashlib.sha256(data).hexdigest()
    if actual != expected_sha256:
        raise BasisError(f"{path}: SHA-256 {actual} is not the {expected_sha256} its model.json names")
    try:
        tensors = load(data)
    except SafetensorError as error:
        raise BasisError(f"{path}: not a readable safetensors file ({error})") from None
    except (KeyError, ValueError, TypeError) as error:  # safetensors.numpy: a dtype NumPy has not (BF16), …
        raise BasisError(f"{path}: a tensor NumPy cannot read ({type(error).__name__}: {error}); a basis file "
                         "holds float16/float32, int8 and int64 tensors") from None
    if "factors" in tensors:
        factorised = _factorised(tensors, str(path))
        return SharedBasis(None, factorised.entries(), actual, factorised)
    components, entries = tensors.get("components"), tensors.get("entries")
    if components is None or entries is None:
        raise BasisError(f"{path}: a basis file needs the tensors 'components' and 'entries', or 'factors', "
                         "'colours', 'factor_of' and 'colour_entries'")
    _validate(components, entries, str(path))
    return SharedBasis(components, entries.astype(np.int64), actual)


def write_factorised_basis(path: str | os.PathLike[str], basis: FactorisedBasis) -> str:
    """Write a factorised basis file atomically and return its SHA-256."""
    from safetensors.numpy import save_file

    from brdfcodec.io.atomic import atomic_output
    from brdfcodec.io.hashing import sha256_of_file

    tensors = {
        "factors": np.ascontiguousarray(basis.factors, dtype=np.float16),
        "colours": np.ascontiguousarray(basis.colours, dtype=np.int64),
        "factor_of": np.ascontiguousarray(basis.factor_of, dtype=np.int64),
        "colour_entries": np.ascontiguousarray(basis.colour_entries, dtype=np.int64),
    }
    if basis.factors_int8 is not None and basis.factor_slice_scales is not None:  # spec/model.md 1.11
        tensors["factors_int8"] = np.ascontiguousarray(basis.factors_int8, dtype=np.int8)
        tensors["factor_slice_scales"] = np.ascontiguousarray(basis.factor_slice_scales, dtype=np.float32)
    _factorised(tensors, str(path))
    with atomic_output(Path(path), overwrite=True) as tmp:
        save_file(tensors, str(tmp))
    return sha256_of_file(path)

def _validate(components: np.ndarray, entries: np.ndarray, where: str) -> None:
    if components.dtype != np.float16 or components.ndim != 2:
        raise BasisError(
            f"{where}: 'components' must be a 2-D float16 tensor, got {components.dtype} {components.shape}"
        )
    if not 1 <= components.shape[0] <= MAX_BASIS_COUNT:
        raise BasisError(f"{where}: a basis holds 1 to {MAX_BASIS_COUNT} vectors, got {components.shape[0]}")
    if entries.ndim != 1 or entries.shape[0] != components.shape[1] or entries.shape[0] == 0:
        raise BasisError(f"{where}: 'entries' must be 1-D with one position per component column")
    if entries.min() < 0 or entries.max() >= _N_ENTRIES or np.any(np.diff(entries) <= 0):
        raise BasisError(f"{where}: 'entries' must be strictly increasing positions in [0, {_N_ENTRIES})")
    if not np.isfinite(components).all():
        raise BasisError(f"{where}: 'components' holds non-finite values")

def basis_reference_target(reference: str, current: str, prefixes: Mapping[str, int]) -> str | None:
    """The full SHA-256 of the one basis a file's ``reference`` names among a model's: its basis ``current`` and
    the earlier ones it extends (``prefixes``, ``spec/model.md`` §5); None when it names none, or two (a short
    reference, format 2.6, is refused rather than resolved by picking one)."""
    named = [full for full in (current, *prefixes) if refers_to(reference, full)]
    return named[0] if len(named) == 1 else None


def model_basis_lookup(folder: str | os.PathLike[str], current: str | None,
                       prefixes: Mapping[str, int]) -> Callable[[str], SharedBasis | None]:
    """``basis_named`` for :func:`check_basis_layers` from a model folder (no torch): its basis
    (``basis.safetensors``, hash ``current``, read and checked against its hash once), or its leading vectors
    where they are an earlier basis (``prefixes``: that basis' hash → its count; ``spec/model.md`` §5)."""
    def basis_named(sha256: str) -> SharedBasis | None:
        named = None if current is None else basis_reference_target(sha256, current, prefixes)
        if named is None:
            return None
        basis = _load_checked(Path(folder) / BASIS_FILE, current)  # type: ignore[arg-type]
        return basis if named == current else basis.leading(prefixes[named], named)

    return basis_named

def _load_checked(path: Path, sha256: str) -> SharedBasis:
    """:func:`load_shared_basis`, kept for the file's size and modification time (``bvae info`` of many files
    reads and hashes a basis once)."""
    stat = path.stat()
    return _load_cached(path, sha256, stat.st_size, stat.st_mtime_ns)

@functools.lru_cache(maxsize=2)
def _load_cached(path: Path, sha256: str, size: int, mtime_ns: int) -> SharedBasis:
    return load_shared_basis(path, sha256)
