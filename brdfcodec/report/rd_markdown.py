"""The rate–distortion part of the report: curves per family and a win/lose table at fixed sizes (issue 14)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from brdfcodec.io.atomic import atomic_output
from brdfcodec.report.styles import distinct_colour_index, distinct_line_style

__all__ = ["TARGET_SIZES", "rd_markdown", "write_rd_plots"]

#: Payload sizes at which the report compares brdfcodec with the best baseline.
TARGET_SIZES = (16, 32, 64, 128, 1024, 16384, 262144)
_METRICS = (("relae_mapped", "RelAE (mapped)"), ("relae_linear", "RelAE (linear)"), ("delta_e_itp", "ΔE ITP"))


def _held(record: dict[str, Any], metric: str) -> float | None:
    errors = record["errors"].get("validation")
    return None if errors is None else float(errors[metric]["mean"])


def _ours(record: dict[str, Any]) -> bool:
    return record["name"].startswith("bvae")


def _best(records: Sequence[dict[str, Any]], size: float, ours: bool, metric: str) -> dict[str, Any] | None:
    fitting = [r for r in records if _ours(r) == ours and r["bytes_per_material"] <= size
               and _held(r, metric) is not None and not r["lossless"]]
    return min(fitting, key=lambda r: _held(r, metric), default=None)  # type: ignore[arg-type,return-value]


def _size(n: float) -> str:
    return f"{n / 1024:g} KB" if n >= 1024 else f"{n:g} B"


def rd_markdown(records: Sequence[dict[str, Any]]) -> str:
    """Markdown: at each target size, the best brdfcodec point and the best baseline within that payload."""
    lines = [
        "",
        "## Rate–distortion at fixed sizes (held-out materials)",
        "",
        "Best point of each side whose mean payload is within the size (held-out mean mapped RelAE; lower is "
        "better). brdfcodec points start with `bvae`; every baseline is packed as its own family says "
        "(`brdfcodec/report/rd_points.py`).",
        "",
        "| size | brdfcodec point | RelAE | best baseline | RelAE | winner |",
        "|---|---|---|---|---|---|",
    ]
    for size in TARGET_SIZES:
        ours, theirs = _best(records, size, True, "relae_mapped"), _best(records, size, False, "relae_mapped")
        a = _held(ours, "relae_mapped") if ours else None
        b = _held(theirs, "relae_mapped") if theirs else None
        if a is None and b is None:
            winner = "–"
        else:
            winner = "brdfcodec" if b is None or (a is not None and a < b) else "baseline"
        lines.append(
            f"| {_size(size)} | {ours['name'] if ours else '–'} | {f'{a:.4g}' if a is not None else '–'} | "
            f"{theirs['name'] if theirs else '–'} | {f'{b:.4g}' if b is not None else '–'} | {winner} |"
        )
    for r in records:
        if r["name"].startswith("bvae-max-relae"):
            worst = r["errors"]["validation"]["relae_mapped"]["worst"]
            lines += ["", f"`{r['name']}`: held-out worst mapped RelAE {worst:.4g}, mean payload "
                      f"{_size(r['bytes_per_material'])}."]
    return "\n".join(lines) + "\n"


def write_rd_plots(records: Sequence[dict[str, Any]], folder: str | Path) -> list[Path]:
    """``rd_<metric>.png``: held-out mean error against bytes per material (log–log), one curve per family."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    families: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        if "validation" in r["errors"] and not r["lossless"]:
            families.setdefault(r.get("family", r["name"]), []).append(r)
    written = []
    for metric, label in _METRICS:
        fig, ax = plt.subplots(figsize=(9.0, 5.0), dpi=110)
        for k, (family, members) in enumerate(sorted(families.items())):
            members = sorted(members, key=lambda r: r["bytes_per_material"])
            xs = [r["bytes_per_material"] for r in members]
            ys = [max(_held(r, metric) or 0.0, 1e-7) for r in members]
            ours = family.startswith("bvae")
            ax.plot(xs, ys, marker="*" if ours else "o", markersize=9 if ours else 4, linewidth=2.2 if ours else 1,
                    color=plt.get_cmap("tab20").colors[distinct_colour_index(k)], linestyle=distinct_line_style(k),
                    label=family)
        for size in TARGET_SIZES:
            ax.axvline(size, color="grey", linewidth=0.5, alpha=0.5)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("bytes per material (record payload)")
        ax.set_ylabel(f"{label}, held-out mean")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=7, frameon=False)
        ax.set_title(f"{records[0]['data']['description']}: rate–distortion ({label})", fontsize=9)
        fig.tight_layout()
        path = Path(folder) / f"rd_{metric}.png"
        with atomic_output(path, overwrite=True) as tmp:
            fig.savefig(tmp, format="png")
        plt.close(fig)
        written.append(path)
    return written
