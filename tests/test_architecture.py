"""The package's architecture, checked: the import-linter contracts of pyproject.toml and no import cycle.

Imports inside functions count (a lazy import that closes a cycle is still a cycle); imports under
``typing.TYPE_CHECKING`` do not.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

grimp = pytest.importorskip("grimp", reason="import-linter (the test extra) is not installed")

ROOT = Path(__file__).resolve().parents[1]

#: Cycles still to break, each as the sorted pair of its modules. Empty is the goal.
KNOWN_CYCLES: set[tuple[str, str]] = set()


def test_import_linter_contracts_are_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    from importlinter.cli import lint_imports

    monkeypatch.chdir(ROOT)  # the contracts live in pyproject.toml
    assert lint_imports(no_cache=True) == 0, "an architecture contract is broken: run `lint-imports` to see which"


def _cycles(graph: grimp.ImportGraph) -> set[tuple[str, str]]:
    cycles = set()
    for importer in graph.modules:
        for imported in graph.find_modules_directly_imported_by(importer):
            if importer != imported and graph.find_shortest_chain(imported, importer) is not None:
                cycles.add(tuple(sorted((importer, imported))))
    return cycles


def test_no_import_cycles_between_modules() -> None:
    graph = grimp.build_graph("brdfcodec", exclude_type_checking_imports=True, cache_dir=None)
    found = _cycles(graph)
    # a cycle between a package and its own module (brdfcodec/__init__ re-exporting) is the package's face
    found = {(a, b) for a, b in found if not (b.startswith(a + ".") or a.startswith(b + "."))}
    assert found <= KNOWN_CYCLES, f"new import cycles (an import of the pair closes a loop): {sorted(found - KNOWN_CYCLES)}"
    assert KNOWN_CYCLES <= found, f"cycles broken since: remove them from KNOWN_CYCLES: {sorted(KNOWN_CYCLES - found)}"


def test_the_cycle_finder_finds_a_cycle(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    package = tmp_path / "loopy"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("def f():\n    from loopy import b\n")
    (package / "b.py").write_text("from loopy import a\n")
    (package / "c.py").write_text("from loopy import a\n")
    monkeypatch.syspath_prepend(os.fspath(tmp_path))
    graph = grimp.build_graph("loopy", cache_dir=None)
    assert _cycles(graph) == {("loopy.a", "loopy.b")}
