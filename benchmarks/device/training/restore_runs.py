"""Rebuild run folders from the device's slim weights: best.pt as `bvae model export` reads it.

usage: python restore_runs.py FILES_AT RUNS_OUT
(FILES_AT: the device tool's files_at, holding logs.tar.gz and models.tar.0, .1, ...; RUNS_OUT: a folder of run
folders for `bvae model export RUN --dataset DATASET`, and device-logs/ with everything the session logged)
The encoder's linear path is rebuilt from the decoder's (as a compact model folder does, spec/model.md §3);
its fully connected layer came back in float16, as the compact export stores it anyway.
"""

import io
import json
import re
import shutil
import sys
import tarfile
from pathlib import Path

import torch

from brdfcodec.models.store import expand_encoder_tensors


def main() -> int:
    files_at, runs_out = Path(sys.argv[1]), Path(sys.argv[2])
    runs_out.mkdir(parents=True, exist_ok=True)
    logs = runs_out / "device-logs"
    with tarfile.open(files_at / "logs.tar.gz") as tar:
        tar.extractall(logs, filter="data")
    chunks = sorted(files_at.glob("models.tar.*"), key=lambda p: int(p.suffix[1:]))
    data = b"".join(p.read_bytes() for p in chunks)
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        for member in tar.getmembers():
            run, _, leaf = member.name.partition("/")
            if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", run) or leaf != "slim.pt" or not member.isfile():
                raise ValueError(f"{files_at}: models archive member {member.name!r} is not RUN/slim.pt")
            state = torch.load(io.BytesIO(tar.extractfile(member).read()), weights_only=True)
            weights = state["model"]
            encoder = {k[len("encoder."):]: v for k, v in weights.items() if k.startswith("encoder.")}
            decoder = {k[len("decoder."):]: v for k, v in weights.items() if k.startswith("decoder.")}
            encoder = expand_encoder_tensors(encoder, decoder)
            model = {**{f"encoder.{k}": v for k, v in encoder.items()},
                     **{f"decoder.{k}": v for k, v in decoder.items()}}
            folder = runs_out / run
            folder.mkdir(exist_ok=True)
            for name in ("log.jsonl", "run.json", "summary.json"):
                source = logs / "logs" / "runs" / run / name
                if source.exists():
                    shutil.copy(source, folder / name)
            torch.save({"model": model, "epoch": state["epoch"], "model_config": state["model_config"]},
                       folder / "best.pt")
            print(run, "epoch", state["epoch"], json.loads(state["model_config"])["latent_dim"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
