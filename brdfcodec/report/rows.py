"""Result rows: one schema for every measured number the project publishes, and the tables made from them.

A row is a flat JSON object. :func:`stamp` adds what makes it traceable:
``schema``, ``study``, ``commit`` (the git commit of the checkout that
measured it, or ``$BRDFCODEC_COMMIT``, or ``"unknown"`` outside a checkout),
``brdfcodec_version`` and ``created`` (UTC). Rows are stored one per line
(JSON Lines); the tables in the documentation are generated from the
project's rows by :func:`summary_markdown` (``bvae bench table``;
documentation: Results).
"""

from __future__ import annotations

import datetime
import json
import os
import subprocess
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.io.atomic import atomic_output
from brdfcodec.version import __version__

__all__ = ["SCHEMA", "current_commit", "rd_plot", "read_rows", "stamp", "summary_markdown", "write_rows"]

#: Schema name and version of a result row.
SCHEMA = "brdfcodec.rows/1"


def current_commit() -> str:
    """The commit measured: ``$BRDFCODEC_COMMIT``, else ``git rev-parse HEAD`` of the package's checkout
    (with ``+dirty`` when it has uncommitted changes), else ``"unknown"``."""
    if os.environ.get("BRDFCODEC_COMMIT"):
        return os.environ["BRDFCODEC_COMMIT"]
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head + ("+dirty" if dirty else "") if head else "unknown"


def stamp(rows: Iterable[dict[str, Any]], *, study: str, **context: Any) -> list[dict[str, Any]]:
    """Rows with the traceability fields (and any ``context`` fields) added in front."""
    header = {"schema": SCHEMA, "study": study, "commit": current_commit(), "brdfcodec_version": __version__,
              "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), **context}
    return [{**header, **row} for row in rows]


def write_rows(path: str | os.PathLike[str], rows: Sequence[dict[str, Any]], *, overwrite: bool = True) -> Path:
    """Write rows as JSON Lines, atomically."""
    with atomic_output(path, overwrite=overwrite) as tmp:
        Path(tmp).write_text("".join(json.dumps(row, sort_keys=True) + "\n" for row in rows), encoding="utf-8")
    return Path(path)


def read_rows(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Rows of a JSON Lines file; refuses rows of another schema.

    Raises
    ------
    ValueError
        A line is not a JSON object of this schema.
    """
    rows = []
    for number, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        row = json.loads(line)
        if not isinstance(row, dict) or row.get("schema") != SCHEMA:
            raise ValueError(f"{path}:{number}: not a row of schema {SCHEMA}")
        rows.append(row)
    return rows


def _pooled(rows: Sequence[dict[str, Any]]) -> tuple[float, float, int]:
    """Mean over every material of the rows (pooled across the folds of a group), bytes per material
    (material-weighted), and the material count."""
    errors = [v for row in rows for v in row["per_material_mapped"]]
    counts = [len(row["per_material_mapped"]) for row in rows]
    size = float(np.average([row["bytes_per_material"] for row in rows], weights=counts))
    return float(np.mean(errors)), size, len(errors)


def summary_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """A Markdown table per group and family: brdfcodec and the best PCA baseline at each budget.

    Rows of one group (the folds of a cross-validation) are pooled over their materials. "best PCA" is, at
    each budget, the PCA point of every variant (as measured or colour-permuted; int8 or float16
    coefficients, transform-coded ``-tc`` or entropy-coded ``-ec-*``) with the lowest pooled mean; "int8/f16
    PCA" is the best of the int8 and float16 points alone (the baseline before issue 48), shown beside it.
    """
    lines: list[str] = []
    groups = sorted({(row["group"], row["family"]) for row in rows})
    for group, family in groups:
        chosen = [row for row in rows if row["group"] == group and row["family"] == family]
        budgets = sorted({row["budget_bytes"] for row in chosen})
        first_pca = min(r["point"] for r in chosen if r["point"].startswith("pca"))
        materials = _pooled([r for r in chosen if r["point"] == first_pca and r["budget_bytes"] == budgets[0]])[2]
        lines += [f"**{group}, held-out {family}** ({materials} materials; mean mapped RelAE, full table; "
                  "bytes per material)", "",
                  "| budget | brdfcodec | bytes | best PCA | PCA point | bytes | int8/f16 PCA | brdfcodec below? |",
                  "|---|---|---|---|---|---|---|---|"]
        for budget in budgets:
            at = [row for row in chosen if row["budget_bytes"] == budget]
            if not any(row["point"] == "bvae" for row in at):
                lines.append(f"| {budget} B | — | — | | | | | no (no file fits: the header's share and the smallest "
                             "records the model writes exceed the budget) |")
                continue
            ours = _pooled([row for row in at if row["point"] == "bvae"])
            pca = min(((point, _pooled([row for row in at if row["point"] == point]))
                       for point in sorted({row["point"] for row in at if row["point"].startswith("pca")})),
                      key=lambda item: item[1][0])
            fixed = [_pooled([row for row in at if row["point"] == point])[0]
                     for point in sorted({row["point"] for row in at if row["point"].startswith("pca")
                                          and row["point"].endswith(("-int8", "-float16"))})]
            lines.append(f"| {budget} B | {ours[0]:.4f} | {ours[1]:.1f} | {pca[1][0]:.4f} | {pca[0]} | "
                         f"{pca[1][1]:.0f} | {f'{min(fixed):.4f}' if fixed else '—'} | "
                         f"{'yes' if ours[0] < pca[1][0] and ours[1] <= budget else 'no'} |")
        lines.append("")
    return "\n".join(lines)


def rd_plot(rows: Sequence[dict[str, Any]], path: str | os.PathLike[str]) -> Path:
    """Rate–distortion panels, one per group and family: brdfcodec against the best PCA envelope.

    x: bytes per material (log scale, file bytes for brdfcodec, payload for PCA); y: pooled mean mapped RelAE,
    on the range of the plotted points only. Written atomically as PNG.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = sorted({(row["group"], row["family"]) for row in rows})
    figure, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.6), squeeze=False)
    for axis, (group, family) in zip(axes[0], panels, strict=True):
        chosen = [row for row in rows if row["group"] == group and row["family"] == family]
        budgets = sorted({row["budget_bytes"] for row in chosen})
        ours = [_pooled([r for r in chosen if r["point"] == "bvae" and r["budget_bytes"] == b]) for b in budgets
                if any(r["point"] == "bvae" and r["budget_bytes"] == b for r in chosen)]
        envelope = []
        for budget in budgets:
            at = [r for r in chosen if r["budget_bytes"] == budget and r["point"].startswith("pca")]
            envelope.append(min((_pooled([r for r in at if r["point"] == p]) for p in {r["point"] for r in at}),
                                key=lambda pooled: pooled[0]))
        axis.plot([o[1] for o in ours], [o[0] for o in ours], "o-", label="brdfcodec (file bytes)")
        axis.plot([e[1] for e in envelope], [e[0] for e in envelope], "s--", label="best PCA, same materials")
        axis.set_xscale("log", base=2)
        axis.set_title(f"{group}: held-out {family}", fontsize=10)
        axis.set_xlabel("bytes per material")
        axis.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("mean mapped RelAE")
    axes[0][0].legend(fontsize=8)
    figure.tight_layout()
    with atomic_output(path, overwrite=True) as tmp:
        figure.savefig(tmp, dpi=110, format="png")
    plt.close(figure)
    return Path(path)
