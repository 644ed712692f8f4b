"""The scripted adversarial pass of issue 11, run by the suite (so in CI).

Every hostile file — the path-traversal library, the metadata and name cases, the 1.5 KB
header-amplification file, every invalid conformance vector — and the degenerate tables go through the
commands a user runs. Each must end with one clean line naming the file, the exit code the README states,
no traceback, and no file anywhere but the output folder.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.cli import main
from brdfcodec.io.merl import write_merl
from brdfcodec.models.manifest import load_manifest
from brdfcodec.models.registry import default_model_folder

ROOT = Path(__file__).resolve().parents[1]
VECTORS = ROOT / "spec" / "vectors"
MANIFEST = json.loads((VECTORS / "manifest.json").read_text(encoding="utf-8"))
SHIPPED = load_manifest(default_model_folder()).decoder_sha256


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def tree(root: Path) -> set[str]:
    return {os.fspath(p.relative_to(root)) for p in root.rglob("*")}


def hostile_library(folder: Path, names: list[str], meta: dict | None = None) -> Path:
    """A library for the shipped decoder, written by hand (the writer would refuse these names)."""
    sys.path.insert(0, str(VECTORS))
    try:
        import make_vectors as mv
    finally:
        sys.path.remove(str(VECTORS))
    payload = np.array([0.0] * 8 + [1.0] * 8, dtype="<f4").tobytes() * len(names)
    descriptors = [mv.descriptor(name, 0) for name in names]
    metadata = b"" if meta is None else json.dumps({"records": {name: meta for name in names}}).encode()
    stored = mv.header([mv.latent_form()], descriptors, payload, dim=8, decoder=SHIPPED, metadata=metadata)
    path = folder / "hostile.bvae"
    path.write_bytes(mv.assemble(stored, payload))
    return path


@pytest.fixture
def sandbox(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    work = tmp_path / "work"
    (work / "out").mkdir(parents=True)
    monkeypatch.chdir(work)
    return tmp_path


def test_path_traversal_library_writes_nothing_outside_the_output(
    capsys: pytest.CaptureFixture[str], sandbox: Path
) -> None:
    escaped = sandbox / "ESCAPED"
    library = hostile_library(sandbox / "work", ["ok", "../UP", str(escaped), ".", ".."])
    before = tree(sandbox)
    for force in ([], ["--force"]):
        code, out, err = run(capsys, "decompress", str(library), "-o", "out/in", *force)
        assert code == 1, err
        assert err.count("\n") == 1 and str(library) in err and "name" in err and "Traceback" not in err
    assert tree(sandbox) == before, "a file appeared"
    assert not escaped.with_suffix(".binary").exists() and not (sandbox / "work" / "out" / "UP.binary").exists()


@pytest.mark.parametrize(
    "meta",
    [{"relae": {"mapped": None}}, {"relae": {"mapped": "x"}}, {"relae": {"mapped": 1e400}}, {"source_sha256": 3}],
    ids=["relae-null", "relae-string", "relae-overflow", "sha-number"],
)
def test_typed_but_wrong_metadata_fails_cleanly_before_writing(
    capsys: pytest.CaptureFixture[str], sandbox: Path, meta: dict
) -> None:
    library = hostile_library(sandbox / "work", ["gold"], meta)
    before = tree(sandbox)
    for argv in (["info", str(library)], ["info", "--json", str(library)],
                 ["decompress", str(library), "-o", "out/gold.binary"],
                 ["extract", str(library), "--material", "gold", "-o", "out/x.bvae"]):
        code, out, err = run(capsys, *argv)
        assert code == 1, (argv, err)
        assert str(library) in err and "meta" in err and "internal error" not in err, err
        assert "Infinity" not in out
    assert tree(sandbox) == before


@pytest.mark.parametrize("vector", MANIFEST["invalid"], ids=lambda v: Path(v["file"]).stem)
@pytest.mark.slow
def test_every_invalid_vector_fails_cleanly_in_every_command(
    capsys: pytest.CaptureFixture[str], sandbox: Path, vector: dict
) -> None:
    path = VECTORS / vector["file"]
    before = tree(sandbox)
    commands = [["info", str(path)], ["info", "--json", str(path)], ["decompress", str(path), "-o", "out/in"]]
    if vector.get("when") != "decode":
        commands.append(["extract", str(path), "--material", "a", "-o", "out/x.bvae"])
    started = time.perf_counter()
    for argv in commands:
        code, out, err = run(capsys, *argv)
        if vector.get("when") == "decode" and argv[0] == "info":
            # well-formed bytes, refused when decoded; info refuses them too where the named decoder is installed
            # (§7: info "refuses what a decoder would", R3-04), as it is here (the vectors name installed models)
            assert code == 1 and str(path) in err and "internal error" not in err, err
            continue
        assert code == 1, (argv, err)
        assert str(path) in err and err.count("\n") == 1 and "internal error" not in err, err
    assert time.perf_counter() - started < 60
    assert tree(sandbox) == before


def test_valid_vectors_give_strict_json_from_info(capsys: pytest.CaptureFixture[str]) -> None:
    for vector in MANIFEST["valid"]:
        code, out, err = run(capsys, "info", "--json", str(VECTORS / vector["file"]))
        assert code == 0, err
        summary = json.loads(out, parse_constant=lambda name: pytest.fail(f"{name} in --json output"))
        assert [m["name"] for m in summary["materials"]] == [r["name"] for r in vector["records"]]


@pytest.mark.parametrize(
    ("label", "value", "code", "expect"),
    [("black", 0.0, 0, "RelAE undefined"), ("nothing-measured", -1.0, 1, "no measured entry"),
     ("denormal", 5e-324, 0, "wrote"), ("huge", 1e308, 0, "clamped"), ("big", 1e30, 0, "clamped")],
)
@pytest.mark.slow
def test_degenerate_tables(
    capsys: pytest.CaptureFixture[str], sandbox: Path, label: str, value: float, code: int, expect: str
) -> None:
    source = sandbox / "work" / f"{label}.binary"
    write_merl(source, np.full((3, 90, 90, 180), value))
    got, out, err = run(capsys, "compress", str(source), "-o", f"out/{label}.bvae")
    assert got == code, err
    assert expect in out + err and "Traceback" not in err and "RuntimeWarning" not in err
    if code == 0:
        got, out, err = run(capsys, "decompress", f"out/{label}.bvae", "-o", f"out/{label}.binary")
        assert got == 0, err
    else:
        assert str(source) in err and not (sandbox / "work" / "out" / f"{label}.bvae").exists()


def test_usage_errors_exit_2(capsys: pytest.CaptureFixture[str], sandbox: Path) -> None:
    from brdfcodec.examples import example_library

    library = str(example_library())
    code, _, err = run(capsys, "edit", "traverse", library, "--material", "gold-paint", "--dim", "9",
                       "-o", "out/t.bvae")
    assert code == 2 and "parameter 9 does not exist" in err and "1 to 8" in err, err
    code, _, err = run(capsys, "render", library, "-o", "out/r.png")
    assert code == 2 and "--material" in err, err
    code, _, err = run(capsys, "edit", "interp", library, "gold-paint", "chrome", "--factors-from-a", "4,12",
                       "-o", "out/t.bvae")
    assert code == 2 and "parameter 12" in err, err
    assert tree(sandbox / "work" / "out") == set()


def _bvae(*args: str, **kwargs: object) -> subprocess.Popen:
    env = {**os.environ, "BVAE_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-m", "brdfcodec", *args], env=env, **kwargs)  # type: ignore[call-overload]


def test_a_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    from brdfcodec.examples import example_library

    process = _bvae("info", "--json", *[str(example_library())] * 40, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout is not None and process.stderr is not None
    process.stdout.read(100)
    process.stdout.close()
    err = process.stderr.read().decode()
    assert process.wait(timeout=120) == 141 and err == "", err


@pytest.mark.slow
def test_sigterm_during_a_library_decompress_leaves_no_partial_file(tmp_path: Path) -> None:
    from brdfcodec.examples import example_library

    out = tmp_path / "out"
    process = _bvae("decompress", str(example_library()), "-o", str(out), stdout=subprocess.DEVNULL,
                    stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (out.is_dir() and any(out.glob("*.binary"))):
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=60) == 143
    assert process.stderr is not None and "terminated" in process.stderr.read().decode()
    assert not [p.name for p in out.iterdir() if p.name.endswith(".part")]
