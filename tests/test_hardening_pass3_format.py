"""Regression tests of the third hardening pass (issue 49), the ``.bvae`` reader's part.

Each defect of ``../shared/redteam-3/README.md`` (R3-…) and of the spec-reader report that concerns the format is
rebuilt here from the project's own writer or byte by byte (``tests/bvae_bytes.py``): the repro files there name
today's model hashes, so the tests do not read them.
"""

from __future__ import annotations

import time
import tracemalloc

import pytest

from brdfcodec.format.strict_json import _check_json_structure, _check_json_text

# --------------------------------------------------------------------------- R3-01, R3-03: the metadata's JSON check


def _refuse(problem: str) -> ValueError:
    return ValueError(problem)


def test_structure_check_of_a_hostile_string_is_linear() -> None:
    """An unterminated string of escaped quotes (``{"a":"\\"\\"…``) made the old regex restart at every quote:
    80 KB took 38 s, so these 2 MB would take hours. Linear, it is refused (by the parse) at once."""
    hostile = b'{"a":"' + b'\\"' * (1 << 20)
    start = time.perf_counter()
    with pytest.raises(ValueError, match="not valid UTF-8 JSON"):
        _check_json_text(hostile, _refuse)
    valid = hostile + b'"}'
    assert _check_json_text(valid, _refuse) == {"a": '"' * (1 << 20)}
    assert time.perf_counter() - start < 2.0


def test_structure_check_memory_is_proportional_to_the_text() -> None:
    """R3-03: one 16 MB string took 2 GB in the check (125 bytes a byte); now a few bytes a byte at most."""
    text = b'{"a":"' + b'\\"' * (2 << 20) + b'"}'
    tracemalloc.start()
    try:
        _check_json_structure(text, _refuse)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 4 * len(text), peak


@pytest.mark.parametrize(("text", "containers", "depth"), [
    (b'{"a":"[[[{{{"}', 1, 1),  # brackets inside a string do not count
    (b'{"a\\"[":["\\\\",[{"b":"\\\\\\"]"}]]}', 4, 4),  # escaped quotes and backslashes before quotes
    (b'{"a":[' + b'"",' * 1000 + b'[]]}', 3, 3),
    (b'[' * 64 + b']' * 64, 64, 64),
])
def test_structure_check_counts_only_brackets_outside_strings(text: bytes, containers: int, depth: int) -> None:
    from brdfcodec.format import strict_json

    outside = _check_json_structure(text, _refuse)
    assert outside.count(b"{") + outside.count(b"[") == containers
    level = deepest = 0
    for byte in outside:
        level += (byte in b"{[") - (byte in b"}]")
        deepest = max(deepest, level)
    assert deepest == depth
    with pytest.raises(ValueError, match="nested 65 levels"):
        _check_json_structure(b"[" * 65 + b"]" * 65, _refuse)
    with pytest.raises(ValueError, match="JSON objects and arrays"):
        _check_json_structure(b"[" + b"[]," * strict_json.MAX_HEADER_CONTAINERS + b"[]]", _refuse)


def test_structure_check_spans_chunks() -> None:
    """A string that straddles the scan's chunks keeps its brackets inside it."""
    from brdfcodec.format import strict_json

    pad = strict_json._SCAN_CHUNK - 7
    text = b'{"a":"' + b"x" * pad + b'[[[{{{\\"]]]"' + b',"b":[[[]]]}'
    outside = _check_json_structure(text, _refuse)
    assert outside.count(b"[") == 3 and outside.count(b"{") == 1
