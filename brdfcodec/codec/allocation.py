"""Library-level rate allocation: one λ for every material of a library (``bvae compress --allocate library``).

Under ``--bytes N`` each record is made the best it can be within N bytes of its own. A library has one size, and
its materials gain unequally from a byte: a diffuse fabric is nearly exact from its latent alone, a metal's error
keeps falling with every coefficient. Library allocation encodes each material at a ladder of record budgets
around N (:func:`budget_ladder`), then keeps for each the rung that minimises the library's summed distortion
within its total bytes (:func:`allocate_bytes`: the equal-slope choice, min Σ Dᵢ + λ Σ Rᵢ with λ searched for the
total). The file format is unchanged: records of different sizes are what a ``.bvae`` file always held.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np

from brdfcodec.codec.rate import lagrangian_hull
from brdfcodec.errors import RateTargetError

__all__ = ["LADDER_FACTORS", "allocate_bytes", "budget_ladder"]

#: The record budgets of the ladder, as fractions of the mean budget N (rounded, at least the smallest record): a
#: material may end up with about 0.6 to 2 times N (what it gains: documentation, Layers and rate control).
LADDER_FACTORS: Final = (0.625, 0.75, 0.875, 1.0, 1.125, 1.25, 1.5, 2.0)


def budget_ladder(mean_bytes: int, smallest: int = 1) -> tuple[int, ...]:
    """The record budgets library allocation encodes each material at, rising.

    Parameters
    ----------
    mean_bytes : int
        N, the mean bytes per record the library is allotted (≥ 1).
    smallest : int, default 1
        No rung below this (the smallest record rate control can make).

    Returns
    -------
    tuple of int
        Distinct budgets, N among them (where N ≥ ``smallest``).
    """
    if mean_bytes < 1:
        raise ValueError(f"the mean budget must be a positive number of bytes, got {mean_bytes}")
    rungs = {max(smallest, int(round(mean_bytes * factor))) for factor in LADDER_FACTORS}
    return tuple(sorted(rungs))


def allocate_bytes(choices: Sequence[Sequence[tuple[int, float]]], total_bytes: int) -> list[int]:
    """For each item, the index of one of its (bytes, distortion) choices, their bytes summing to at most
    ``total_bytes``, with the summed distortion as low as the equal-slope rule makes it.

    Each item's choices are reduced to the lower convex hull of its (R, D) points (:func:`lagrangian_hull`). From
    every item's smallest hull point, the hull step of the largest distortion saved per byte that still fits is
    taken, one at a time (the Lagrangian solution for each λ the steps pass, exact where the total falls on a hull
    vertex); then the bytes left over go, item by item in order of the distortion they save, to any larger choice
    of lower distortion that fits.

    Parameters
    ----------
    choices : sequence of sequences of (int, float)
        Per item, its candidates: bytes (≥ 0) and distortion (finite; lower is better). At least one each.
    total_bytes : int
        The most bytes all the chosen candidates may take together.

    Returns
    -------
    list of int
        Per item, the index of the chosen candidate in its sequence.

    Raises
    ------
    RateTargetError
        The smallest candidates together exceed ``total_bytes``.
    ValueError
        An item without candidates, or a distortion that is not finite.
    """
    hulls: list[list[int]] = []
    for i, options in enumerate(choices):
        if not options:
            raise ValueError(f"item {i} has no candidate")
        if not all(np.isfinite(d) for _, d in options):
            raise ValueError(f"item {i} has a distortion that is not finite")
        # by rising bytes, the smallest candidate first (of its bytes, the one of least distortion)
        hulls.append([index for index, _, _ in lagrangian_hull([(float(r), float(d)) for r, d in options])])
    position = [0] * len(choices)
    used = sum(choices[i][hull[0]][0] for i, hull in enumerate(hulls))
    if used > total_bytes:
        raise RateTargetError(f"the smallest records take {used} bytes together, above the {total_bytes} allotted")
    while True:
        best: tuple[float, int] | None = None
        for i, hull in enumerate(hulls):
            if position[i] + 1 < len(hull):
                here, there = choices[i][hull[position[i]]], choices[i][hull[position[i] + 1]]
                extra = there[0] - here[0]
                if used + extra <= total_bytes:
                    slope = (here[1] - there[1]) / max(extra, 1e-9)
                    if best is None or slope > best[0]:
                        best = (slope, i)
        if best is None:
            break
        i = best[1]
        used += choices[i][hulls[i][position[i] + 1]][0] - choices[i][hulls[i][position[i]]][0]
        position[i] += 1
    chosen = [hull[position[i]] for i, hull in enumerate(hulls)]
    # the bytes the hull steps could not use: any larger choice of lower distortion that still fits
    while True:
        best_fill: tuple[float, int, int] | None = None
        for i, options in enumerate(choices):
            r, d = options[chosen[i]]
            for j, (rj, dj) in enumerate(options):
                if rj > r and dj < d and used + rj - r <= total_bytes and (best_fill is None or d - dj > best_fill[0]):
                    best_fill = (d - dj, i, j)
        if best_fill is None:
            break
        _, i, j = best_fill
        used += choices[i][j][0] - choices[i][chosen[i]][0]
        chosen[i] = j
    return chosen

