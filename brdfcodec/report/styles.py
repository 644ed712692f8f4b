"""Plot styles that tell many curves apart: every colour of matplotlib's ``tab20``, then line styles."""

from __future__ import annotations

from typing import Final

__all__ = ["LINE_STYLES", "distinct_colour_index", "distinct_line_style"]

#: Line styles of the curves past the first 20 (then every 20 more).
LINE_STYLES: Final = ("-", "--", ":", "-.")
_COLOURS: Final = 20


def distinct_colour_index(k: int) -> int:
    """Index into ``tab20`` of the k-th curve (k ≥ 0): the 10 dark shades first, then the 10 light ones.

    The first 20 curves get 20 different colours; the k-th and the (k + 20)-th share one
    (:func:`distinct_line_style` tells them apart).

    Examples
    --------
    >>> [distinct_colour_index(k) for k in (0, 1, 9, 10, 11, 19, 20)]
    [0, 2, 18, 1, 3, 19, 0]
    """
    if k < 0:
        raise ValueError(f"curve index must be >= 0, got {k}")
    k %= _COLOURS
    return (2 * k) % _COLOURS + k // (_COLOURS // 2)


def distinct_line_style(k: int) -> str:
    """Line style of the k-th curve (k ≥ 0): solid for the first 20, then dashed, dotted, dash-dotted.

    Examples
    --------
    >>> [distinct_line_style(k) for k in (0, 19, 20, 40, 60, 80)]
    ['-', '-', '--', ':', '-.', '-']
    """
    if k < 0:
        raise ValueError(f"curve index must be >= 0, got {k}")
    return LINE_STYLES[(k // _COLOURS) % len(LINE_STYLES)]
