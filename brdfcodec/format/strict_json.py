"""Strict JSON for ``.bvae`` metadata (``spec/bvae-format.md`` §3.1).

Canonical text on write; bounded, exact parsing on read.

Part of :mod:`brdfcodec.format.bvae`, which re-exports its names.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

import numpy as np

from brdfcodec.format.container import MAX_HEADER_CONTAINERS, MAX_HEADER_DEPTH, MAX_JSON_INTEGER
from brdfcodec.format.material_names import MAX_NAME_LENGTH as MAX_NAME_LENGTH  # re-exported
from brdfcodec.format.records import MAX_LATENT_DIM as MAX_LATENT_DIM  # re-exported


def canonical_json(value: Any) -> bytes:
    """The canonical UTF-8 JSON text of a header (§3.1): sorted keys, no white space, shortest numbers.

    Raises
    ------
    ValueError
        The value holds something JSON cannot carry in a ``.bvae`` header:
        NaN or infinity, an integer beyond ±(2⁵³ − 1), a lone surrogate, a
        duplicate key after conversion to text, or a non-JSON type.
    """
    try:
        text = json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
        data = text.encode("utf-8")
    except (TypeError, ValueError, UnicodeEncodeError, RecursionError) as error:
        raise ValueError(f"record metadata must be JSON values (finite numbers, valid Unicode): {error}") from None
    outside_strings = _check_json_structure(data, ValueError)  # keys are unique: they come from dicts
    for match in _LONG_INTEGER.finditer(outside_strings):
        if abs(int(match.group())) > MAX_JSON_INTEGER:
            raise ValueError(f"record metadata holds the integer {match.group()[:40].decode()}, beyond ±(2^53 - 1)")
    return data


def _check_json_structure(data: bytes, fail: Any) -> bytes:
    """The bounds of §3 on JSON objects and arrays (their number, their nesting); returns the text without strings.

    Linear in time and bounded in memory (a few MB beyond the text): escapes are removed with
    :meth:`bytes.replace`, then every byte's place inside or outside a string is the parity of the quotes
    before it, computed in chunks with NumPy. No regular expression that could backtrack over a hostile
    string (issue 49, R3-01 and R3-03), and no Python object per token.

    The string contents are removed; each string's closing quote is kept (as a separator), so numbers outside
    strings keep their neighbours. For text that is not valid JSON the counts may be off, but then the parse
    that follows refuses it (an unterminated string counts as running to the end).
    """
    # Inside a string, "\\" and "\"" are the only escapes that involve a backslash or a quote; removing the
    # backslash pairs first (left to right, as a run of backslashes pairs up) leaves every remaining backslash
    # escaping the character after it, so that removing "\"" leaves only the quotes that delimit strings.
    unescaped = data.replace(b"\\\\", b"").replace(b'\\"', b"")
    text = np.frombuffer(unescaped, dtype=np.uint8)
    kept: list[bytes] = []
    containers = depth = deepest = 0
    inside = 0  # parity of the quotes before the chunk
    for start in range(0, text.size, _SCAN_CHUNK):
        chunk = text[start : start + _SCAN_CHUNK]
        quotes = chunk == _QUOTE
        # cumulative parity (uint8 wraps modulo 256, which keeps it): 1 on an opening quote and the string's
        # content, 0 on its closing quote and outside
        parity = (np.cumsum(quotes, dtype=np.uint8) + np.uint8(inside)) & np.uint8(1)
        outside = chunk[parity == 0]
        inside = int(parity[-1])
        opens = (outside == _OPEN_OBJECT) | (outside == _OPEN_ARRAY)
        closes = (outside == _CLOSE_OBJECT) | (outside == _CLOSE_ARRAY)
        containers += int(np.count_nonzero(opens))
        if containers > MAX_HEADER_CONTAINERS:
            raise fail(f"header holds more than {MAX_HEADER_CONTAINERS} JSON objects and arrays")
        steps = opens[opens | closes].astype(np.int32) * 2 - 1
        if steps.size:
            levels = np.cumsum(steps) + depth
            deepest, depth = max(deepest, int(levels.max())), int(levels[-1])
        if deepest > MAX_HEADER_DEPTH:
            raise fail(f"header JSON is nested {deepest} levels deep, more than {MAX_HEADER_DEPTH}")
        kept.append(outside.tobytes())
    return b"".join(kept)


def _check_json_text(data: bytes, fail: Any) -> Any:
    """Parse header JSON under the rules and bounds of §3 (raises ``fail(message)`` on any breach)."""
    _check_json_structure(data, fail)
    try:
        value = json.loads(
            data.decode("utf-8"),
            parse_constant=_reject_constant,
            parse_float=_finite_float,
            parse_int=_exact_int,
            object_pairs_hook=_unique_keys,
        )
    except (UnicodeDecodeError, ValueError, RecursionError) as error:
        raise fail(f"header is not valid UTF-8 JSON ({error})") from None
    try:  # lone surrogates ("\ud800") are valid JSON escapes but not Unicode text
        json.dumps(value, ensure_ascii=False).encode("utf-8")
    except UnicodeEncodeError:
        raise fail("header holds a lone surrogate escape (not Unicode text)") from None
    return value


#: An integer token of 16 digits or more (2^53 has 16): the only ones that can exceed ±(2^53 - 1).
_LONG_INTEGER = re.compile(rb"(?<![0-9.eE+-])-?[0-9]{16,}(?![0-9.eE])")
#: Bytes of the text the structure check looks at a time (its working memory is a few times this).
_SCAN_CHUNK = 1 << 20
_QUOTE, _OPEN_OBJECT, _OPEN_ARRAY, _CLOSE_OBJECT, _CLOSE_ARRAY = (ord(c) for c in '"{[}]')


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:40]} overflows binary64 (infinity is not allowed)")
    return value


def _exact_int(text: str) -> int:
    value = int(text)
    if abs(value) > MAX_JSON_INTEGER:
        raise ValueError(f"integer {text[:40]} exceeds ±(2^53 - 1)")
    return value


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    result = dict(pairs)
    if len(result) != len(pairs):
        keys = [k for k, _ in pairs]
        repeated = sorted({k for k in keys if keys.count(k) > 1})
        raise ValueError(f"duplicate key {repeated[0]!r} in a JSON object")
    return result


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not allowed in a .bvae header")
