"""Every Python snippet of the README runs as written, in order, in an empty folder.

The documentation site's pages are tested the same way (tests/test_docs.py); .ci/run runs the README's
first code block's two commands.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def python_snippets() -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.S | re.M)


def test_readme_has_the_snippets_it_documents() -> None:
    snippets = python_snippets()
    assert len(snippets) >= 1
    assert "wi = " in snippets[0] and "wo = " in snippets[0], "wi and wo are defined where they are first used"


@pytest.mark.slow
def test_readme_python_snippets_run_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "readme"}
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no silent NaN/zero-direction warnings either
        for index, snippet in enumerate(python_snippets()):
            code = compile(snippet, f"README.md python snippet {index + 1}", "exec")
            exec(code, namespace)  # noqa: S102 - the README is the code under test
    assert np.asarray(namespace["rgb"]).shape == (2, 3) and np.isfinite(namespace["rgb"]).all()
    assert (tmp_path / "lib.bvae").is_file()
