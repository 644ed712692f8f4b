"""Report files: one JSON record per operating point, a Markdown table, and PNG plots (matplotlib)."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from brdfcodec.io.atomic import atomic_output
from brdfcodec.report.styles import distinct_colour_index

__all__ = ["markdown_table", "write_report"]

_FLOOR = 1e-7  # lossless points are drawn at this RelAE on the log axes


def _size(n: float) -> str:
    for unit, scale in (("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n:.0f} B"


def _split(record: dict[str, Any]) -> str:
    return "validation" if "validation" in record["errors"] else "all"


def markdown_table(records: Sequence[dict[str, Any]]) -> str:
    """The report as a Markdown table (held-out materials first; training materials apart)."""
    data = records[0]["data"]
    lines = [
        f"Data: **{data['description']}** ({data['source_kind']}; {data['materials']} materials, "
        f"{data['train']} training / {data['validation']} held out). Device: {records[0]['device']}. "
        "RelAE is the mapped RelAE of `spec/conventions.md` §8 on the full table; ΔE ITP / ΔE 2000 are means over a "
        "64² sphere render under a directional light; times are medians per material.",
        "",
        "| operating point | bytes / material | shared bytes | RelAE held-out mean | p90 | worst | RelAE train mean "
        "| ΔE ITP (held-out) | ΔE 2000 (held-out) | encode ms | decode ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in records:
        held = r["errors"][_split(r)]
        train = r["errors"].get("train")
        relae = held["relae_mapped"]
        lines.append(
            "| " + " | ".join([
                r["name"],
                _size(r["bytes_per_material"]),
                _size(r["shared_bytes"]) if r["shared_bytes"] else "–",
                f"{relae['mean']:.4g}",
                f"{relae['p90']:.4g}",
                f"{relae['worst']:.4g} ({relae['worst_material']})",
                f"{train['relae_mapped']['mean']:.4g}" if train else "–",
                f"{held['delta_e_itp']['mean']:.3g}",
                f"{held['delta_e_2000']['mean']:.3g}",
                f"{r['encode_ms_median']:.1f}",
                f"{r['decode_ms_median']:.1f}",
            ]) + " |"
        )
    return "\n".join(lines) + "\n"


def _plot(records: Sequence[dict[str, Any]], x_key: str, x_label: str, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.0, 4.8), dpi=110)
    colours = plt.get_cmap("tab20").colors
    markers = "ovs^D<>phX8"
    for k, r in enumerate(records):
        relae = max(r["errors"][_split(r)]["relae_mapped"]["mean"], _FLOOR)
        bvae = r["name"].startswith("bvae")
        label = r["name"] + (" (lossless, drawn at 1e-7)" if relae <= _FLOOR else "")
        ax.scatter([max(r[x_key], 1e-3)], [relae], s=110 if bvae else 40, marker="*" if bvae else markers[k % 11],
                   color=colours[distinct_colour_index(k)], edgecolors="black", linewidths=0.4, zorder=3, label=label)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=7, frameon=False)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(x_label)
    ax.set_ylabel("RelAE (mapped), held-out mean")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    with atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def write_report(folder: str | os.PathLike[str], records: Sequence[dict[str, Any]],
                 rows: Sequence[dict[str, Any]]) -> list[Path]:
    """Write ``report.jsonl``, ``materials.jsonl``, ``report.md`` and two plots into ``folder``.

    Every row of the two JSON Lines files names the commit it was measured at (``commit``,
    :func:`brdfcodec.report.rows.current_commit`).
    """
    from brdfcodec.report.rows import current_commit

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    commit = current_commit()
    records = [{"commit": commit, **item} for item in records]
    rows = [{"commit": commit, **item} for item in rows]
    for name, items in (("report.jsonl", records), ("materials.jsonl", rows)):
        with atomic_output(out / name, overwrite=True) as tmp:
            tmp.write_text("".join(json.dumps(item, sort_keys=True) + "\n" for item in items), encoding="utf-8")
        written.append(out / name)
    from brdfcodec.report.rd_markdown import rd_markdown, write_rd_plots  # issue 14: rate–distortion section

    with atomic_output(out / "report.md", overwrite=True) as tmp:
        tmp.write_text(markdown_table(records) + rd_markdown(records), encoding="utf-8")
    written.append(out / "report.md")
    written += write_rd_plots(records, out)
    overview = [r for r in records if not r.get("held_out_only")] or list(records)
    data = records[0]["data"]["description"]
    for key, label, file in (
        ("decode_ms_median", "decode time per material (ms, median)", "relae_vs_decode_time.png"),
        ("bytes_per_material", "bytes per material", "relae_vs_bytes.png"),
    ):
        _plot(overview, key, label, out / file, f"{data}: RelAE against {label.split(' (')[0]}")
        written.append(out / file)
    return written
