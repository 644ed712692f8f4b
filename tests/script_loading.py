"""Load a repository script (a benchmark, the docs' hooks, the vectors' generator) as a module, by its path: the
scripts are not in an importable package."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

__all__ = ["REPO_ROOT", "load_script"]

REPO_ROOT = Path(__file__).resolve().parents[1]


def load_script(path: Path, name: str | None = None) -> ModuleType:
    """The module of the Python file ``path``, executed afresh, named ``name`` (the file's stem by default)."""
    spec = importlib.util.spec_from_file_location(name or path.stem, path)
    assert spec is not None and spec.loader is not None, f"{path} is not a Python file"
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
