"""Command-line behaviour the adversarial pass asked for: thread settings, exit codes as documented, outputs
named in errors, ignored outputs (issue 11, usability)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from script_loading import load_script

from brdfcodec.cli.main import (
    EXIT_BROKEN_PIPE,
    EXIT_ERROR,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_TERMINATED,
    EXIT_USAGE,
    configure_threads,
    default_thread_count,
    main,
)

ROOT = Path(__file__).resolve().parents[1]


def test_thread_count_defaults_and_overrides(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("brdfcodec.runtime.threads.available_cores", lambda: 64)  # above the cores: test_thread_limits
    assert default_thread_count(2) == 1 and default_thread_count(1) == 1
    assert default_thread_count(16) == 8 and default_thread_count(64) == 8
    env: dict[str, str] = {}
    assert configure_threads(env) == default_thread_count() and env["OMP_NUM_THREADS"] == str(default_thread_count())
    assert configure_threads({"OMP_NUM_THREADS": "3"}) == 3
    env = {"BVAE_NUM_THREADS": "2", "OMP_NUM_THREADS": "5"}
    assert configure_threads(env) == 2 and env["OMP_NUM_THREADS"] == "2"
    assert configure_threads({"BVAE_NUM_THREADS": "many"}) == default_thread_count()


@pytest.mark.slow
def test_a_command_line_run_sizes_torch_threads() -> None:
    code = ("import sys, torch; from brdfcodec.cli.main import main; sys.argv = ['bvae', 'model', 'list']; "
            "main(); print('THREADS', torch.get_num_threads())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"PATH": "/usr/bin:/bin", "BVAE_NUM_THREADS": "1"}).stdout
    assert "THREADS 1" in out


def _cli_reference() -> str:
    """The documentation site's command-line reference (docs/hooks.py generates it from the parser)."""
    return load_script(ROOT / "docs" / "hooks.py", "docs_hooks").cli_reference()


def test_docs_state_the_exit_codes_the_cli_uses() -> None:
    readme = _cli_reference()
    text = " ".join(readme.replace("|", " ").split())
    for code, meaning in [(0, "success"), (EXIT_ERROR, "bad input"), (EXIT_USAGE, "usage errors"),
                          (EXIT_INTERNAL, "internal error"), (EXIT_INTERRUPTED, "interrupted"),
                          (EXIT_BROKEN_PIPE, "standard output closed early"), (EXIT_TERMINATED, "terminated")]:
        assert re.search(rf"\b{code} {meaning}", text), (code, meaning)
    assert "BVAE_NUM_THREADS" in readme


def test_outputs_of_the_readme_commands_are_ignored_but_shipped_files_are_not() -> None:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    ignored = subprocess.run(["git", "check-ignore", "gold.bvae", "gold.binary", "gold-decoded.binary",
                              "lib.bvae", "edits.bvae"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    assert ignored == ["gold.bvae", "gold.binary", "gold-decoded.binary", "lib.bvae", "edits.bvae"]
    for shipped in ("brdfcodec/data/libraries/nbrdf-proxy-90.bvae", "spec/vectors/valid/library.bvae"):
        result = subprocess.run(["git", "check-ignore", "-q", shipped], cwd=ROOT)
        assert result.returncode == 1, f"{shipped} would be ignored"


def test_unwritable_output_names_the_output(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    blocked = tmp_path / "file"
    blocked.write_text("")
    code = main(["analytic", "gold", "-o", str(blocked / "gold.binary")])
    err = capsys.readouterr().err
    assert code == 1 and str(blocked / "gold.binary") in err and ".part" not in err, err


def test_cli_reference_names_every_command_and_option() -> None:
    """The documentation's command-line reference lists every sub-command and its long options."""
    import argparse

    from brdfcodec.cli.main import build_parser

    readme = table = _cli_reference()
    general = {"--help", "--version", "--force", "--quiet", "--output"}  # -o in the table; --force below it

    def walk(parser: argparse.ArgumentParser, path: tuple[str, ...]) -> list[tuple[tuple[str, ...], list[str]]]:
        found = [(path, [o for a in parser._actions for o in a.option_strings if o.startswith("--")])]
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    found += walk(sub, (*path, name))
        return found

    missing = []
    for path, options in walk(build_parser(), ()):
        if not path:
            continue
        command = "bvae " + " ".join(path)
        if command not in table:
            missing.append(command)
        if path == ("train",):
            continue  # "--epochs, --lr, ..., ...": the rest is in `bvae train --help`
        missing += [f"{command} {o}" for o in options if o not in general and not re.search(rf"{o}\b", table)]
    assert not missing, missing
    assert "--force" in readme and "--json" in table
