"""libLLVM discovery for Mitsuba's LLVM variants."""

from __future__ import annotations

from pathlib import Path

import pytest

from brdfcodec import mitsuba_runtime
from brdfcodec.mitsuba_runtime import configure_libllvm, find_libllvm, libllvm_version


@pytest.mark.parametrize(
    ("name", "version"),
    [("libLLVM-19.so", 19), ("libLLVM.so.19.1", 19), ("libLLVM-15.so.1", 15), ("libLLVM-14.0.6.so.1", 14),
     ("libLLVM.dylib", None), ("libfoo.so", None)],
)
def test_version_from_file_name(name: str, version: int | None) -> None:
    assert libllvm_version(name) == version


def test_environment_variable_wins(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    chosen = tmp_path / "libLLVM-17.so"
    chosen.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(chosen))
    assert find_libllvm() == chosen


def test_newest_usable_version_is_chosen_and_old_ones_skipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    files = {v: tmp_path / f"libLLVM-{v}.so" for v in (14, 15, 18, 19)}
    for path in files.values():
        path.write_bytes(b"")
    monkeypatch.setattr(mitsuba_runtime, "candidate_libllvm_paths",
                        lambda: sorted(files.values(), key=lambda p: -(libllvm_version(p) or 0)))
    assert find_libllvm() == files[19]
    monkeypatch.setattr(mitsuba_runtime, "candidate_libllvm_paths", lambda: [files[15], files[14]])
    assert find_libllvm() is None
    with pytest.warns(RuntimeWarning, match="libllvm19"):
        assert configure_libllvm(warn=True) is None
