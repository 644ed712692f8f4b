"""MkDocs hooks of the documentation site (``mkdocs.yml``: ``hooks``).

- ``cli.md`` is generated from ``bvae``'s own argparse parser: the ``--help`` of
  every sub-command, so the command-line reference cannot drift from the code.
- The normative ``spec/`` folder, the committed ``reports/``, ``benchmarks/README.md``
  and the two models' cards (the default's, the editing model's) are added to the site under their repository paths.
- Pages under ``docs/`` link to those files as ``../spec/...`` (which also works when the
  Markdown is read on a forge); the links are rewritten to the site's layout at build time.

Nothing here touches the network.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Repository folders and files copied into the site under the same relative path.
EXTRA_TREES = ("spec", "reports")
EXTRA_FILES = ("benchmarks/README.md", "benchmarks/rd/README.md", "brdfcodec/data/models/default/MODEL_CARD.md",
               "packages/brdfcodec-editing-model/brdfcodec_editing_model/models/editing/MODEL_CARD.md")
EXTRA_SUFFIXES = {".md", ".png", ".json", ".jsonl", ".txt", ".csv", ".svg", ".py", ".sh"}


def _sub_commands(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser]]:
    """(name, parser) of every sub-command below ``parser``, depth first, in registration order."""
    found: list[tuple[str, argparse.ArgumentParser]] = []
    for action in parser._actions:  # noqa: SLF001 - argparse keeps sub-parsers here
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for name, sub in action.choices.items():
                found.append((name, sub))
                found.extend((f"{name} {child}", child_parser) for child, child_parser in _sub_commands(sub))
    return found


def _help(parser: argparse.ArgumentParser) -> str:
    """``parser``'s help, wrapped at 100 columns whatever the terminal (argparse reads ``$COLUMNS``)."""
    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        return parser.format_help().rstrip()
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous


def cli_reference() -> str:
    """The command-line reference page, from ``brdfcodec.cli.main.build_parser``."""
    from brdfcodec.cli.main import build_parser

    parser = build_parser()
    parts = [
        "# Command line reference\n",
        "Generated from `bvae`'s argument parser when the site is built: each section is the "
        "output of `bvae COMMAND --help`. The [quick start](quickstart.md) shows the commands in use; "
        "[exit codes, outputs and threads](#exit-codes-and-outputs) are described at the end.\n",
        "```text\n" + _help(parser) + "\n```\n",
    ]
    for name, sub in _sub_commands(parser):
        parts.append(f"## bvae {name}\n")
        parts.append("```text\n" + _help(sub) + "\n```\n")
    usage = (Path(__file__).parent / "cli-notes.md").read_text(encoding="utf-8")
    parts.append(usage)
    return "\n".join(parts)


def on_files(files, config):  # noqa: ANN001, ANN201 - MkDocs' hook signature
    from mkdocs.structure.files import File  # imported here so that tests can import this module without MkDocs

    files.append(File.generated(config, "cli.md", content=cli_reference()))
    for tree in EXTRA_TREES:
        for path in sorted((ROOT / tree).rglob("*")):
            if path.is_file() and path.suffix in EXTRA_SUFFIXES:
                files.append(File.generated(config, path.relative_to(ROOT).as_posix(), abs_src_path=str(path)))
    for name in EXTRA_FILES:
        files.append(File.generated(config, name, abs_src_path=str(ROOT / name)))
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ANN001 - MkDocs' hook signature
    """Pages of docs/ link to repository files as ``../X``; on the site those files live at ``X``."""
    if page.file.generated_by:
        return markdown
    depth = page.file.src_uri.count("/")  # docs/api/x.md links to the repository root as ../../
    return markdown.replace("](" + "../" * (depth + 1), "](" + "../" * depth)
