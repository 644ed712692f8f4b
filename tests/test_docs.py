"""The documentation site (docs/, mkdocs.yml): its Python examples run as written, every page is in the
navigation, and the generated command-line reference covers every sub-command and option.

Each page's ```python blocks run in order, in an empty folder, in one namespace per page (as a reader
would paste them). A page whose examples need an optional package says so on a line of its own:
``<!-- docs-test: requires mitsuba -->``; the test then skips when the package is missing. A page may
also name the files its examples write, ``<!-- docs-test: creates edits.bvae gold.png -->``, and the
test checks they were written.
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import warnings
from pathlib import Path

import pytest
from script_loading import load_script

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
_REQUIRES = re.compile(r"^<!-- docs-test: requires ([\w.]+) -->$", re.M)
_CREATES = re.compile(r"^<!-- docs-test: creates ([^>]+) -->$", re.M)


def _pages() -> list[Path]:
    return sorted(path for path in DOCS.rglob("*.md") if path.name != "cli-notes.md")


def python_blocks(page: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", page.read_text(encoding="utf-8"), flags=re.S | re.M)


def _pages_with_examples() -> list[Path]:
    return [page for page in _pages() if python_blocks(page)]


def _hooks():  # noqa: ANN202 - the docs' MkDocs hook module, loaded from its file
    return load_script(DOCS / "hooks.py", "docs_hooks")


def test_the_guide_pages_have_examples() -> None:
    names = {page.name for page in _pages_with_examples()}
    assert {"quickstart.md", "python-api.md", "rate-control.md", "editing.md"} <= names


@pytest.mark.slow
@pytest.mark.parametrize("page", _pages_with_examples(), ids=lambda page: page.relative_to(DOCS).as_posix())
def test_page_python_examples_run_as_written(page: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for module in _REQUIRES.findall(page.read_text(encoding="utf-8")):
        pytest.importorskip(module)
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "docs"}
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for index, block in enumerate(python_blocks(page)):
            exec(compile(block, f"{page.relative_to(ROOT)} python block {index + 1}", "exec"), namespace)  # noqa: S102
    for names in _CREATES.findall(page.read_text(encoding="utf-8")):
        for name in names.split():
            assert (tmp_path / name).is_file(), f"{page.name}'s examples did not write {name}"


def test_every_page_is_in_the_navigation() -> None:
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    listed = set(re.findall(r"^\s*- (?:[^:\n]+: )?([\w/.-]+\.md)\s*$", config, flags=re.M))
    pages = {page.relative_to(DOCS).as_posix() for page in _pages()}
    assert pages - listed == set(), "pages missing from mkdocs.yml's nav"
    assert listed - pages - {"cli.md"} == set(), "nav entries without a page (cli.md is generated)"


def _parsers(parser: argparse.ArgumentParser, prefix: str = "bvae"):  # noqa: ANN202
    yield prefix, parser
    for action in parser._actions:  # noqa: SLF001
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for name, sub in action.choices.items():
                yield from _parsers(sub, f"{prefix} {name}")


def test_cli_reference_names_every_sub_command_and_option() -> None:
    from brdfcodec.cli.main import build_parser

    page = _hooks().cli_reference()
    for name, parser in _parsers(build_parser()):
        if name != "bvae":
            assert f"## {name}\n" in page, name
        for action in parser._actions:  # noqa: SLF001
            for option in action.option_strings:
                assert option in page, f"{name} {option}"


def test_api_reference_names_existing_modules() -> None:
    """The API pages' ``::: module`` lines (the one list of documented modules) name importable modules."""
    names = [name for page in (DOCS / "api").glob("*.md")
             for name in re.findall(r"^::: ([\w.]+)$", page.read_text(encoding="utf-8"), flags=re.M)]
    assert names
    for name in names:
        assert importlib.util.find_spec(name) is not None, name


def test_quoted_results_are_rows_of_the_generated_report() -> None:
    """Measured numbers live in generated files: rate–distortion lines quoted in the README or on the Results
    page (``| group | family (n) | model (decoder) | commit | …``, made by ``bvae bench table --results-table``)
    are copied verbatim from a table under ``reports/results/`` (regenerate it, then copy its lines again),
    and each names the decoder hash and commit that measured it."""
    generated = {line.strip() for path in (ROOT / "reports" / "results").glob("*.md")
                 for line in path.read_text(encoding="utf-8").splitlines() if line.startswith("|")}
    quoted = 0
    for source in (ROOT / "README.md", DOCS / "results.md"):
        for line in source.read_text(encoding="utf-8").splitlines():
            if re.match(r"\| [^|]+ \| [\w-]+ \(\d+\) \| [^|]+ \([0-9a-f]{12}\) \| ", line):
                assert line.strip() in generated, f"{source.name}: not a line of reports/results/*.md: {line}"
                assert re.search(r"\([0-9a-f]{12}\)", line) and re.search(r"\| [0-9a-f]{7} \|", line), line
                quoted += 1
    assert quoted, "the Results page quotes the generated rate–distortion tables"
