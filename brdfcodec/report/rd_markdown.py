"""The rate–distortion part of the report: curves per family and a win/lose table at fixed sizes (issue 14)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from brdfcodec.io.atomic import atomic_output
from brdfcodec.report.styles import distinct_colour_index, distinct_line_style

__all__ = ["TARGET_SIZES", "rd_markdown", "results_table", "write_decode_time_plot", "write_rd_plots"]

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


def write_decode_time_plot(rows: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """Error against decode time, every point: one panel per group and family of ``bvae bench rd`` rows.

    Each row with a decode time (``decode_ms_median``, per material, from the stored bytes to the full
    table) is one marker: x its decode time (ms, log scale), y its mean mapped RelAE over the row's
    materials; marker and colour name the point (``bvae``, ``pca-tc``, …), the label beside it the budget.
    Rows of one group, point and budget (the folds of a cross-validation) are pooled: material-weighted
    mean error, median of their decode times. The machine the times were measured on
    (``decode_machine``) is in the title.

    Raises
    ------
    ValueError
        No row has a decode time.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    timed = [r for r in rows if r.get("decode_ms_median") is not None]
    if not timed:
        raise ValueError("no row has a decode time (decode_ms_median): rows made before decode times were measured")
    panels = sorted({(r["group"], r["family"]) for r in timed})
    kinds = sorted({r["point"] for r in timed}, key=lambda k: (k != "bvae", k))
    markers = "*osD^v<>phX"
    figure, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.4), squeeze=False)
    for axis, (group, family) in zip(axes[0], panels, strict=True):
        chosen = [r for r in timed if r["group"] == group and r["family"] == family]
        for k, kind in enumerate(kinds):
            points = []
            for budget in sorted({r["budget_bytes"] for r in chosen if r["point"] == kind}):
                at = [r for r in chosen if r["point"] == kind and r["budget_bytes"] == budget]
                errors = [v for r in at for v in r["per_material_mapped"]]
                points.append((float(np.median([r["decode_ms_median"] for r in at])), float(np.mean(errors)),
                               budget))
            if not points:
                continue
            ours = kind == "bvae"
            axis.scatter([p[0] for p in points], [p[1] for p in points], marker=markers[k % len(markers)],
                         s=90 if ours else 28, zorder=3 if ours else 2, label=kind,
                         color=plt.get_cmap("tab20").colors[distinct_colour_index(k)])
            for x, y, budget in points:
                axis.annotate(_size(budget), (x, y), fontsize=6, xytext=(3, 2), textcoords="offset points")
        axis.set_xscale("log")
        axis.set_yscale("log")
        axis.set_title(f"{group}: {family}", fontsize=10)
        axis.set_xlabel("decode time per material (ms, median)")
        axis.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("mean mapped RelAE")
    axes[0][-1].legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=7, frameon=False)
    machines = sorted({str(r.get("decode_machine", "machine not recorded")) for r in timed})
    figure.suptitle("Error against decode time, every point (labels: budget per material); " + "; ".join(machines),
                    fontsize=8)
    figure.tight_layout()
    with atomic_output(path, overwrite=True) as tmp:
        figure.savefig(tmp, dpi=110, format="png")
    plt.close(figure)
    return Path(path)


def _pooled(rows: Sequence[dict[str, Any]]) -> tuple[float, float, float | None]:
    """Material-weighted mean error and bytes of rows (the folds of a group), and their median decode time."""
    import numpy as np

    errors = [v for r in rows for v in r["per_material_mapped"]]
    counts = [len(r["per_material_mapped"]) for r in rows]
    size = float(np.average([r["bytes_per_material"] for r in rows], weights=counts))
    times = [r["decode_ms_median"] for r in rows if r.get("decode_ms_median") is not None]
    return float(np.mean(errors)), size, float(np.median(times)) if times else None


def _ms(value: float | None) -> str:
    return "—" if value is None else f"{value:.3g}"


def results_table(rows: Sequence[dict[str, Any]]) -> str:
    """One Markdown table of ``bvae bench rd`` rows for the Results page: a line per group, family and budget.

    Each line names what measured it — the model, the first 12 hex digits of its decoder's SHA-256, the
    commit (first 7) — and compares brdfcodec (pooled over the group's rows) with the best of every PCA
    variant at that budget (lowest pooled mean mapped RelAE), each with its bytes per material and its
    median decode time per material (ms, from the stored bytes to the full table; "—" in rows made before
    decode times were measured). "brdfcodec below?" is "yes" when brdfcodec's error is lower and its bytes
    within the budget.
    """
    lines = ["| group | family (materials) | model (decoder sha256) | commit | latent | budget | brdfcodec | bytes "
             "| decode ms | best PCA | PCA point | bytes | decode ms | brdfcodec below? |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for group, family in sorted({(r["group"], r["family"]) for r in rows}):
        chosen = [r for r in rows if r["group"] == group and r["family"] == family]
        ours_rows = [r for r in chosen if r["point"] == "bvae"]
        models = sorted({f"{r['model']} ({r['decoder_sha256'][:12]})" for r in ours_rows})
        commits = sorted({str(r["commit"])[:7] for r in chosen})
        latent = sorted({str(r.get("latent", "auto")) for r in ours_rows})
        for budget in sorted({r["budget_bytes"] for r in chosen}):
            at = [r for r in chosen if r["budget_bytes"] == budget]
            mine = [r for r in at if r["point"] == "bvae"]
            points = sorted({r["point"] for r in at if r["point"].startswith("pca")})
            if not mine or not points:
                continue
            materials = sum(len(r["per_material_mapped"]) for r in mine)
            ours = _pooled(mine)
            best, pca = min(((p, _pooled([r for r in at if r["point"] == p])) for p in points),
                            key=lambda item: item[1][0])
            below = "yes" if ours[0] < pca[0] and ours[1] <= budget else "**no**"
            if not any(p.endswith(("-tc", "-ec-laplace", "-ec-gaussian")) for p in points):
                best += " (int8/f16 only: rows made before the coded PCA)"
            lines.append(f"| {group} | {family} ({materials}) | {', '.join(models)} | {', '.join(commits)} | "
                         f"{', '.join(latent)} | {_size(budget)} | {ours[0]:.4f} | {ours[1]:.1f} | {_ms(ours[2])} | "
                         f"{pca[0]:.4f} | {best} | {pca[1]:.0f} | {_ms(pca[2])} | {below} |")
    return "\n".join(lines) + "\n"
