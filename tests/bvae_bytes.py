"""The conformance vectors' hand-written ``.bvae`` writer (``spec/vectors/make_vectors.py``), for tests that
build files byte by byte, independently of ``brdfcodec.format.bvae``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from script_loading import load_script

_PATH = Path(__file__).resolve().parents[1] / "spec" / "vectors" / "make_vectors.py"


def _load() -> Any:
    return load_script(_PATH)


bytes_writer = _load()
