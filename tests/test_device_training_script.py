"""The device session's training runner (``benchmarks/device/training``) rehearsed on the CPU: two runs side by side
on ten NBRDF proxies, scored, packed into chunks the device tool returns, and rebuilt into run folders whose
``best.pt`` loads as the model it trained."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from brdfcodec.models.config import ModelConfig
from brdfcodec.models.network import BetaVAE
from brdfcodec.training.checkpoint import load_checkpoint

ROOT = Path(__file__).resolve().parents[1]
TRAINING = ROOT / "benchmarks" / "device" / "training"

pytestmark = pytest.mark.slow


def test_the_runner_trains_scores_packs_and_the_runs_come_back(nbrdf_zip: Path, tmp_path: Path) -> None:
    configs = tmp_path / "two.configs"
    configs.write_text("# name  arguments\nfree --factor-weight 0\nsupervised --factor-weight 10000\n")
    out, work = tmp_path / "out", tmp_path / "work"
    out.mkdir()
    environment = {**os.environ, "OUT": str(out), "WORK": str(work), "COMMIT": "test", "QUICK": "1",
                   "DATA": str(nbrdf_zip.parent), "CONFIGS": str(configs), "BENCH_S": "0",
                   "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    done = subprocess.run(["bash", str(TRAINING / "train_side_by_side.sh")], cwd=ROOT, env=environment,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    chunks = sorted(out.glob("models.tar.*"))
    assert chunks and all(chunk.stat().st_size <= 15_000_000 for chunk in chunks)  # the device tool's 16 MB files
    assert sum(chunk.stat().st_size for chunk in chunks) <= 63_000_000

    restored = tmp_path / "runs"
    done = subprocess.run([sys.executable, str(TRAINING / "restore_runs.py"), str(out), str(restored)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rows = {json.loads(line)["run"]: json.loads(line)
            for line in (restored / "device-logs" / "logs" / "eval.jsonl").read_text().splitlines() if line.strip()}
    assert set(rows) == {"free", "supervised"}
    for name, row in rows.items():
        assert "error" not in row, row
        assert 0 <= row["mig"] <= 1 and 0 <= row["dci_d"] <= 1 and 0 < row["relae"]["merl"] < 1
        required = {"model": dict, "epoch": int, "model_config": str}
        state = load_checkpoint(restored / name / "best.pt", required=required)
        model = BetaVAE(ModelConfig.from_dict(json.loads(state["model_config"])))
        model.load_state_dict(state["model"])  # every tensor back, the encoder's linear path rebuilt
        trained = torch.load(work / "runs" / name / "best.pt", weights_only=True)["model"]
        assert torch.equal(state["model"]["decoder.fc.2.weight"], trained["decoder.fc.2.weight"])  # the decoder exact
        assert (restored / name / "run.json").is_file() and (restored / name / "log.jsonl").is_file()
