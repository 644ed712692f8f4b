"""Where the bytes of `bvae compress --bytes N` go, before and after a change of rate control (issue 48, 2).

For each material and budget, in one process and alternating (a paired measurement on the same machine load), the
encode with rate control as it was at ``--before-commit`` (``brdfcodec/codec/rate.py`` and ``encoding.py`` read
from git, with that commit's default options; the rest of the package as checked out) and with the checkout's own
(its default options): the full-table mapped RelAE, the encode time, each record's bytes (descriptor, μ, σ, basis
step, coefficients, detail) and, after, every candidate rate control measured (label, rate R in bytes, kept-slice
mapped L1 distortion D). Writes rows (schema ``brdfcodec.rows/1``, study ``rate-control-rd``) and a Markdown
summary beside them.

usage: python scripts/rate_control_rd.py OUT.jsonl --before-commit SHA [--budgets 16,32,64,128] FILE...
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np


def breakdown(record: Any) -> dict[str, Any]:
    """A record's bytes beyond its name: descriptor (``overhead``), μ, σ, basis step and coefficients, detail."""
    from brdfcodec.format.writer import descriptor_size, record_size
    from brdfcodec.layers.basis import STEP_BYTES

    parts: dict[str, Any] = {"name_bytes": len(record.name.encode()), "overhead": descriptor_size(record),
                             "record_bytes": record_size(record, "float32")}
    if getattr(record, "kind", "latent") != "layered":
        return {**parts, "mu": 4 * record.latent_dim, "sigma": 4 * record.latent_dim, "latent": True}
    mu = 0
    if record.has_latent:
        mu = record.latent_dim + (0 if record.fixed_mu_grid else 2) if record.compact_mu else 4 * record.latent_dim
    sigma = 0
    if record.has_latent and record.store_sigma:
        sigma = 1 if record.shared_sigma else (record.latent_dim if record.compact_sigma else 4 * record.latent_dim)
    parts.update(mu=mu, sigma=sigma, latent=bool(record.has_latent))
    if record.basis is not None:
        layer = record.basis
        coding = "coded" if layer.prior is not None else ("packed" if layer.top else "int8")
        step = 0 if coding == "coded" else STEP_BYTES  # a coded layer's step code is among its bytes
        parts.update(basis_coding=coding, basis_count=layer.count, basis_first=layer.first, project=layer.project,
                     basis_step=step, coefficients=len(layer.data) - step)
    if record.detail is not None:
        parts.update(detail=record.detail.nbytes, detail_step=float(record.detail.step))
    return parts


def _old_modules(commit: str) -> Any:
    """``layer_records`` and ``EncodeOptions`` of rate control at ``commit`` (its rate.py and encoding.py)."""
    folder = Path(tempfile.mkdtemp(prefix="rate-before-"))
    for name in ("rate", "encoding"):
        text = subprocess.run(["git", "show", f"{commit}:brdfcodec/codec/{name}.py"], capture_output=True,
                              text=True, check=True).stdout
        text = text.replace("from brdfcodec.codec.rate import", "from _before_rate import")
        (folder / f"_before_{name}.py").write_text(text, encoding="utf-8")
    sys.path.insert(0, str(folder))
    spec = importlib.util.spec_from_file_location("_before_encoding", folder / "_before_encoding.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["_before_encoding"] = module
    spec.loader.exec_module(module)
    return module


def measure_pairs(files: list[str], budgets: list[int], before_commit: str) -> list[dict[str, Any]]:
    import brdfcodec.codec.encoding as encoding
    from brdfcodec.codec import BrdfEncoder, measure
    from brdfcodec.codec.prepare import prepare_source
    from brdfcodec.datasets.sources import input_sources

    before = _old_modules(before_commit)
    points: list[list[tuple[str, int, float]]] = []
    own = encoding.encode_layers

    def spy(*args: Any, **kwargs: Any) -> Any:
        result = own(*args, **kwargs)
        points.append([(p.label, p.rate, p.distortion) for p in result.points])
        return result

    encoding.encode_layers = spy
    rows = []
    for path in files:
        source = input_sources(path)[0]
        brdf = prepare_source(source.load().brdf)
        for budget in budgets:
            for which in ("before", "after"):
                encoder = BrdfEncoder(bytes=budget)
                if which == "before":  # that commit's rate control and default options
                    defaults = before.EncodeOptions()
                    encoder.options = before.EncodeOptions(bytes_budget=budget, effort=defaults.effort)
                    encoding.layer_records, saved = before.layer_records, encoding.layer_records
                try:
                    start = time.perf_counter()
                    record = encoder.encode(brdf, name=source.name)
                    seconds = time.perf_counter() - start
                finally:
                    if which == "before":
                        encoding.layer_records = saved
                relae = measure(record, encoder.decoder, brdf).meta["relae"]
                row = {"point": which, "budget_bytes": budget, "material": source.name, "source": path,
                       "mapped_relae": relae["mapped"], "linear_relae": relae["linear"], "encode_s": seconds,
                       "commit_measured": before_commit if which == "before" else None, **breakdown(record)}
                if which == "after":
                    row["candidates"] = [{"label": label, "rate": rate, "distortion": d}
                                         for label, rate, d in points[-1]]
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def summary(rows: list[dict[str, Any]]) -> str:
    """Markdown: mean RelAE and encode time per budget before and after, then each record's bytes."""
    budgets = sorted({r["budget_bytes"] for r in rows})
    materials = sorted({r["material"] for r in rows})
    lines = [f"Mean mapped RelAE (full table) over {len(materials)} materials no model here was trained on "
             f"({', '.join(materials)}), and encode seconds per material (paired, same process, busy 2-core "
             "machine):", "",
             "| budget | before RelAE | after RelAE | change | before s | after s | time ratio |",
             "|---|---|---|---|---|---|---|"]
    for budget in budgets:
        at = {w: [r for r in rows if r["budget_bytes"] == budget and r["point"] == w] for w in ("before", "after")}
        if not at["before"] or not at["after"]:
            continue
        b, a = (float(np.mean([r["mapped_relae"] for r in at[w]])) for w in ("before", "after"))
        tb, ta = (float(np.mean([r["encode_s"] for r in at[w]])) for w in ("before", "after"))
        lines.append(f"| {budget} B | {b:.4f} | {a:.4f} | {100 * (a / b - 1):+.1f} % | {tb:.1f} | {ta:.1f} | "
                     f"{ta / tb:.2f} |")
    lines += ["", "Each record's bytes beyond its name (descriptor + μ + σ + basis step + coefficients + detail):",
              "",
              "| budget | material | point | RelAE | bytes | descriptor | μ | σ | basis (coding, count, first "
              "vector) | step | coefficients | detail |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for budget in budgets:
        for material in materials:
            for r in rows:
                if r["budget_bytes"] != budget or r["material"] != material:
                    continue
                basis = (f"{r['basis_coding']}, {r['basis_count']}, {r['basis_first']}" if "basis_coding" in r
                         else "—")
                lines.append(f"| {budget} B | {material} | {r['point']} | {r['mapped_relae']:.4f} | "
                             f"{r['record_bytes']} | {r['overhead']} | {r['mu']} | {r['sigma']} | {basis} | "
                             f"{r.get('basis_step', '—')} | {r.get('coefficients', '—')} | {r.get('detail', '—')} |")
    lines += ["", "Candidates rate control measured after the change (rate R in bytes, kept-slice mapped L1 "
              "distortion D; the chosen one has the lowest D of those with R ≤ the budget):", ""]
    for r in rows:
        if r["point"] == "after":
            points = "; ".join(f"{c['label']}: R {c['rate']}, D {c['distortion']:.0f}"
                               for c in r["candidates"])
            lines.append(f"- {r['budget_bytes']} B {r['material']}: {points}")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", type=Path, help="rows (.jsonl); the summary is written beside it (.md)")
    parser.add_argument("files", nargs="+", help="material files (MERL .binary, RGL .bsdf)")
    parser.add_argument("--before-commit", required=True, help="commit whose rate control is the baseline")
    parser.add_argument("--budgets", default="16,32,64,128")
    parser.add_argument("--from-json", type=Path, help="rows measured already (a JSON list): only write them")
    args = parser.parse_args()
    from brdfcodec.report.rows import stamp, write_rows

    budgets = [int(b) for b in args.budgets.split(",")]
    if args.from_json is not None:
        rows = json.loads(args.from_json.read_text(encoding="utf-8"))
    else:
        rows = measure_pairs(args.files, budgets, args.before_commit)
    command = "python scripts/rate_control_rd.py " + " ".join(sys.argv[1:])
    stamped = stamp(rows, study="rate-control-rd", command=command, before_commit=args.before_commit)
    write_rows(args.output, stamped)
    args.output.with_suffix(".md").write_text(summary(rows), encoding="utf-8")


if __name__ == "__main__":
    main()
