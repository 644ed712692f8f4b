"""The conformance vectors' hand-written ``.bvae`` writer (``spec/vectors/make_vectors.py``), for tests that
build files byte by byte, independently of ``brdfcodec.format.bvae``."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

_PATH = Path(__file__).resolve().parents[1] / "spec" / "vectors" / "make_vectors.py"


def _load() -> Any:
    spec = importlib.util.spec_from_file_location("make_vectors", _PATH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


bytes_writer = _load()
