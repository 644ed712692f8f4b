"""Summarise the fine-tuning trials of issue 41 (v3 recipe): python reports/model-v3-trials/summarise.py

Reads each release/<trial>/ folder (model-info.json from the exported trial model, plausibility.json or .txt of
`bvae model plausibility` on the 120 NBRDF proxies, plausibility-analytic30.txt on the 30 analytic materials) and
writes summary.md beside this file.
"""
import json
import re
from pathlib import Path

HERE = Path(__file__).parent
ALL_LINE = re.compile(r"^All .*")


def totals(text: str) -> dict[str, float]:
    line = next(l for l in text.splitlines() if ALL_LINE.match(l))
    return {k: float(v) for k, v in re.findall(r"(\w+) (\d+\.\d+)", line.split(":", 1)[1])}


rows = []
for folder in sorted((HERE / "release").iterdir()):
    info = json.loads((folder / "model-info.json").read_text())
    if (folder / "plausibility.json").exists():
        fractions = json.loads((folder / "plausibility.json").read_text())["fractions"]
        plaus = {k: sum(map(sum, v)) / sum(map(len, v)) for k, v in fractions.items()}
    else:
        plaus = totals((folder / "plausibility.txt").read_text())
    analytic = folder / "plausibility-analytic30.txt"
    held = totals(analytic.read_text()).get("highlight") if analytic.exists() else None
    t = info["train_config"]
    rows.append((folder.name, t["epochs"], t["traversal_weight"], t.get("traversal_hole_margin", 0.0),
                 t.get("traversal_pit_weight", 0.0), info["summary"]["train"]["mapped_mean"], plaus.get("inverted"),
                 plaus.get("holes"), plaus.get("highlight"), plaus.get("pits"), held))


def cell(value: float | None, digits: int = 4) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


lines = ["| trial | epochs | penalty weight | hole margin | pit weight | mapped RelAE (120, trained) | inverted | holes "
         "| highlight | pits | highlight, 30 analytic |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
for r in rows:
    lines.append(f"| {r[0]} | {r[1]} | {r[2]:g} | {r[3]:g} | {r[4]:g} | {cell(r[5])} | {cell(r[6], 3)} | "
                 f"{cell(r[7], 3)} | {cell(r[8], 3)} | {cell(r[9], 3)} | {cell(r[10], 3)} |")
(HERE / "summary.md").write_text("\n".join(lines) + "\n")
print("\n".join(lines))
