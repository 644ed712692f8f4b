"""The device benchmark script (issue 51, item 7) runs on the CPU: its rows are of the project's one schema, the
CUDA-only measurements are rows that say why they did not run, a spent budget skips with a row, and its mapped
difference is the project's mapping over the entries above the horizon."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from script_loading import load_script

from brdfcodec.report.rows import SCHEMA, read_rows

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "device" / "device_benchmark.py"


def _script() -> ModuleType:
    return load_script(SCRIPT)


def _run(out: Path, *extra: str) -> list[dict]:
    """The script in its own process (a Mitsuba variant it sets stays out of this one)."""
    done = subprocess.run([sys.executable, str(SCRIPT), "--out", str(out), "--device", "cpu", "--quick", *extra],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    return read_rows(out / "device-benchmark.jsonl")  # refuses rows of another schema


def _run_here(out: Path, monkeypatch: pytest.MonkeyPatch, *extra: str) -> list[dict]:
    """The script in this process (no second torch import), its commit pinned by the environment."""
    monkeypatch.setenv("BRDFCODEC_COMMIT", "0123abc")
    assert _script().main(["--out", str(out), "--device", "cpu", "--quick", *extra]) == 0
    return read_rows(out / "device-benchmark.jsonl")


def _traceable(rows: list[dict], command_part: str) -> None:
    for row in rows:
        assert row["schema"] == SCHEMA and row["study"] == "device-benchmark"
        assert row["commit"] and row["device"].startswith("cpu (") and command_part in row["command"]
        assert row["command"].startswith("python benchmarks/device/device_benchmark.py --out ")
        assert row["status"] in ("measured", "skipped", "failed", "loaded")
        if row["status"] != "measured":
            assert row["reason"], row


def test_quick_cpu_run_writes_rows_and_skips_the_cuda_stages_with_reasons(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rows = _run_here(tmp_path, monkeypatch, "--stages", "environment,throughput,cross-device", "--latents", "2",
                     "--batches", "2")
    _traceable(rows, "--device cpu --quick")
    assert {row["commit"] for row in rows} == {"0123abc"}
    by = {(row["stage"], row["measurement"], row.get("batch_size")): row for row in rows}
    environment = by["environment", "environment", None]
    assert environment["torch"] and environment["tf32_cudnn"] in (True, False)
    for name in ("network-fp32", "decode_many", "decode_many_tensor"):
        row = by["throughput", name, 2]
        assert row["status"] == "measured" and row["latents"] == 2 and np.isfinite(row["tables_per_s"])
        assert row["tables_per_s"] > 0
    assert by["throughput", "decode_many", 2]["share_of_network_fp32"] > 0
    assert by["throughput", "best-decode", None]["meets_target"] is False  # 10,000 tables/s: not on this CPU
    assert "CUDA" in by["throughput", "network-fp16", 2]["reason"]
    for measurement in ("random-latents", "vectors"):
        row = by["cross-device", measurement, None]
        assert row["status"] == "skipped" and "other than the CPU" in row["reason"]
    assert (tmp_path / "device-benchmark.md").read_text(encoding="utf-8").count("\n| ") == len(rows) + 1


def test_a_spent_budget_skips_each_measurement_with_a_row(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rows = _run_here(tmp_path, monkeypatch, "--stages", "environment,throughput", "--budget-s", "0.000001")
    _traceable(rows, "--budget-s 0.000001")
    assert [row["status"] for row in rows if row["stage"] == "environment"] == ["measured"]  # costs nothing
    skipped = [row for row in rows if row["stage"] != "environment"]
    assert skipped and all(row["status"] == "skipped" and "time budget spent" in row["reason"] for row in skipped)


def test_bad_arguments_are_a_usage_error(tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as exit_:
        _script().main(["--out", str(tmp_path), "--stages", "environment,warp"])
    assert exit_.value.code == 2 and not (tmp_path / "device-benchmark.jsonl").exists()


def test_mapped_difference_is_the_mapping_above_the_horizon() -> None:
    torch = pytest.importorskip("torch")
    from brdfcodec.representation.mapping import map_values
    from brdfcodec.representation.mask import horizon_mask

    script = _script()
    rng = np.random.default_rng(3)
    values = rng.uniform(0, 5e4, (3, 4, 2, 2)).astype(np.float32)
    np.testing.assert_allclose(script.mapped_tensor(torch.from_numpy(values)).numpy(),
                               map_values(values.astype(np.float64)), rtol=1e-12, atol=1e-12)
    tables = np.full((2, 3, 90, 90, 180), 7.0, np.float32)
    other = tables.copy()
    below = np.argwhere(~horizon_mask())[0]
    above = np.argwhere(horizon_mask())[0]
    other[0, 1, below[0], below[1], below[2]] += 1e4  # below the horizon: not counted
    other[1, 2, above[0], above[1], above[2]] = 14.0  # above: counted
    delta = script.max_mapped_difference(torch.from_numpy(tables), torch.from_numpy(other)).numpy()
    expected = map_values(np.full((3, 1), 14.0))[2, 0] - map_values(np.full((3, 1), 7.0))[2, 0]
    assert delta[0] == 0.0
    assert delta[1] == pytest.approx(expected, rel=1e-9)


def test_llvm_reference_is_used_only_at_the_same_size_and_spp(tmp_path: Path) -> None:
    script = _script()
    image = np.ones((14, 24, 3), np.float32)
    reference = tmp_path / "renders.npz"
    meta = json.dumps({"spp": 2, "width": 24, "height": 14})
    np.savez_compressed(reference, meta=np.array(meta), llvm_ad_rgb_seed0=image, llvm_ad_rgb_seed1=image * 2)
    args = script.parse_arguments(["--out", str(tmp_path), "--device", "cpu", "--quick",
                                   "--llvm-reference", str(reference)])
    renders: dict[str, np.ndarray] = {}
    row = script._load_renders(args, reference, "llvm_ad_rgb_seed", "llvm-reference", renders)
    assert row["status"] == "loaded" and sorted(renders) == ["llvm_ad_rgb_seed0", "llvm_ad_rgb_seed1"]
    renders.clear()
    row = script._load_renders(args, reference, "cuda_ad_rgb_seed", "cuda-renders", renders)
    assert row["status"] == "skipped" and "no cuda_ad_rgb_seed" in row["reason"] and not renders
    args.spp = 64
    row = script._load_renders(args, reference, "llvm_ad_rgb_seed", "llvm-reference", renders)
    assert row["status"] == "skipped" and "'spp': 2" in row["reason"] and not renders


@pytest.mark.parametrize(("brightness", "agrees"), [(1 + 1e-6, True), (1.3, False)], ids=["agree", "brighter"])
def test_cuda_renders_are_held_to_the_llvm_seed_spread_seed_by_seed(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, brightness: float, agrees: bool) -> None:
    """Each CUDA seed as the LLVM one up to float rounding; then seed 1 a third brighter (a backend that
    disagrees)."""
    pytest.importorskip("mitsuba", reason="the render stage needs Mitsuba 3 (pip install 'brdfcodec[mitsuba]')")
    rng = np.random.default_rng(3)
    seed0 = (0.3 + 0.2 * rng.random((14, 24, 3))).astype(np.float32)
    seed1 = (seed0 * (1 + 0.1 * rng.standard_normal(seed0.shape))).astype(np.float32)
    meta = np.array(json.dumps({"spp": 2, "width": 24, "height": 14}))
    llvm = tmp_path / "llvm.npz"
    np.savez_compressed(llvm, meta=meta, llvm_ad_rgb_seed0=seed0, llvm_ad_rgb_seed1=seed1)
    cuda = tmp_path / "cuda.npz"
    np.savez_compressed(cuda, meta=meta, cuda_ad_rgb_seed0=seed0 * np.float32(1 + 1e-6),
                        cuda_ad_rgb_seed1=seed1 * np.float32(brightness))
    rows = _run_here(tmp_path / "rows", monkeypatch, "--stages", "render", "--llvm-reference", str(llvm),
                     "--renders", str(cuda))
    by = {row["measurement"]: row for row in rows}
    assert "llvm_ad_rgb" not in by and "cuda_ad_rgb" not in by  # compared, not rendered
    assert by["llvm-reference"]["status"] == by["cuda-renders"]["status"] == "loaded"
    spread = by["llvm-seed-spread"]["delta_e_itp_mean"]
    assert spread > 0 and by["cuda-vs-llvm-seed0"]["llvm_seed_spread_delta_e_itp_mean"] == spread
    assert by["cuda-vs-llvm-seed0"]["meets_target"] and by["cuda-vs-llvm-seed0"]["delta_e_itp_mean"] < 0.01 * spread
    assert by["cuda-vs-llvm-seed1"]["meets_target"] is agrees
    assert (by["cuda-vs-llvm-seed1"]["delta_e_itp_mean"] < 0.01 * spread) is agrees
    other = by["cuda-vs-llvm-other-seed"]  # LLVM seed 0 against CUDA seed 1: the spread, kept without a target
    assert "meets_target" not in other and (other["delta_e_itp_mean"] == pytest.approx(spread, rel=1e-3)) is agrees


@pytest.mark.slow
def test_quick_cpu_render_stage_skips_cuda_with_a_reason(tmp_path: Path) -> None:
    rows = _run(tmp_path, "--stages", "environment,render")
    _traceable(rows, "--stages environment,render")
    assert len({row["commit"] for row in rows}) == 1  # one commit, though another session may commit meanwhile
    cuda = [row for row in rows if row["measurement"] == "cuda_ad_rgb"]
    assert len(cuda) == 1 and cuda[0]["status"] == "skipped" and "CUDA" in cuda[0]["reason"]
    llvm = [row for row in rows if row["measurement"] == "llvm_ad_rgb"]
    assert llvm and all(row["status"] in ("measured", "skipped") for row in llvm)
    if all(row["status"] == "measured" for row in llvm):
        assert all(row["finite"] and row["mean_radiance"] > 0 for row in llvm)
        spread = next(row for row in rows if row["measurement"] == "llvm-seed-spread")
        assert spread["status"] == "measured" and spread["delta_e_itp_mean"] > 0  # two seeds differ
        with np.load(tmp_path / "renders.npz") as renders:
            assert renders["llvm_ad_rgb_seed0"].shape == (14, 24, 3)
