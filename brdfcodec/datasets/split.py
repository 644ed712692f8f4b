"""Deterministic train/validation split of named materials.

Materials are split *per family* (:func:`split_by_family`), so every
measurement family has held-out materials; within a family, a material's
rank is the SHA-256 of ``"{seed}:{name}"``; the
``round(fraction · n)`` lowest-ranked materials (at least one when
``fraction > 0`` and there are two or more materials) go to validation. The
split depends only on names, seed and fraction, never on input order, NumPy
version or platform, and adding materials moves few of the existing ones.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

__all__ = ["TRAIN", "VALIDATION", "fold_by_family", "split_by_family", "split_materials"]

TRAIN = "train"
VALIDATION = "validation"


def _rank(seed: int, name: str) -> bytes:
    return hashlib.sha256(f"{seed}:{name}".encode()).digest()


def split_materials(names: Sequence[str], *, validation_fraction: float = 0.15, seed: int = 0) -> list[str]:
    """Assign each material to ``"train"`` or ``"validation"``.

    Parameters
    ----------
    names : sequence of str
        Distinct material names.
    validation_fraction : float, default 0.15
        Share of materials held out, in [0, 1).
    seed : int, default 0
        Changes the draw.

    Returns
    -------
    list of str
        ``"train"`` or ``"validation"`` for each name, in the input order.
    """
    if not 0.0 <= validation_fraction < 1.0:
        raise ValueError(f"validation_fraction must be in [0, 1), got {validation_fraction}")
    if len(set(names)) != len(names):
        raise ValueError("material names must be distinct")
    n = len(names)
    n_validation = round(validation_fraction * n)
    if validation_fraction > 0 and n >= 2:
        n_validation = min(max(n_validation, 1), n - 1)
    held_out = set(sorted(names, key=lambda name: _rank(seed, name))[:n_validation])
    return [VALIDATION if name in held_out else TRAIN for name in names]


def split_by_family(
    names: Sequence[str], families: Sequence[str], *, validation_fraction: float = 0.15, seed: int = 0
) -> list[str]:
    """:func:`split_materials` applied within each family, so every family is held out in proportion.

    A dataset of one family splits exactly as :func:`split_materials`.

    Parameters
    ----------
    names : sequence of str
        Distinct material names.
    families : sequence of str
        Each material's family (``"merl"``, ``"rgl"``, ...), same length as ``names``.
    validation_fraction : float, default 0.15
        Share of each family held out, in [0, 1).
    seed : int, default 0

    Returns
    -------
    list of str
        ``"train"`` or ``"validation"`` for each name, in the input order.
    """
    if len(families) != len(names):
        raise ValueError(f"got {len(names)} names but {len(families)} families")
    if len(set(names)) != len(names):
        raise ValueError("material names must be distinct")
    result = [TRAIN] * len(names)
    for family in sorted(set(families)):
        members = [i for i, f in enumerate(families) if f == family]
        for i, side in zip(members, split_materials([names[i] for i in members],
                                                    validation_fraction=validation_fraction, seed=seed), strict=True):
            result[i] = side
    return result


def fold_by_family(names: Sequence[str], families: Sequence[str], *, folds: int, seed: int = 0) -> list[int]:
    """Stratified k-fold assignment: each family's materials dealt in rank order over ``folds`` folds.

    Within a family, materials are ranked as in :func:`split_materials` (SHA-256 of ``"{seed}:{name}"``) and
    the material of rank r goes to fold ``r mod folds``, so every fold holds ``⌊n/folds⌋`` or ``⌈n/folds⌉`` of
    each family's n materials, and the assignment depends only on names, families, seed and ``folds``.

    Parameters
    ----------
    names : sequence of str
        Distinct material names.
    families : sequence of str
        Each material's family, same length as ``names``.
    folds : int
        Number of folds, ≥ 2.
    seed : int, default 0

    Returns
    -------
    list of int
        The fold (0 to ``folds`` − 1) of each name, in the input order.

    Examples
    --------
    >>> fold_by_family(["a", "b", "c", "d"], ["x", "x", "y", "y"], folds=2).count(0)
    2
    """
    if folds < 2:
        raise ValueError(f"folds must be at least 2, got {folds}")
    if len(families) != len(names):
        raise ValueError(f"got {len(names)} names but {len(families)} families")
    if len(set(names)) != len(names):
        raise ValueError("material names must be distinct")
    result = [0] * len(names)
    for family in sorted(set(families)):
        members = sorted((i for i, f in enumerate(families) if f == family), key=lambda i: _rank(seed, names[i]))
        for rank, i in enumerate(members):
            result[i] = rank % folds
    return result
