"""``bvae bench report``: size, error and run time of the codec against the alternatives, on a dataset."""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

__all__ = ["register"]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``bench`` sub-command."""
    parser = subparsers.add_parser(
        "bench",
        help="reports: size, error and run time against baselines",
        description="Benchmark reports. Timed micro-benchmarks with same-run baselines live in the source "
        "checkout: python -m pytest benchmarks.",
    )
    ops = parser.add_subparsers(dest="operation", metavar="OPERATION")
    ops.required = True
    report = ops.add_parser(
        "report",
        help="evaluate the shipped model and baselines on a dataset; write JSON, Markdown and PNG plots",
        description="For every operating point (the shipped model with float32 and float16 latents; PCA of the "
        "mapped slices at several sizes; the 21 kept slices alone; the raw table in float32 and float16, with "
        "and without zstandard) measure bytes per material, shared bytes, RelAE (mean, median, p90, worst; "
        "held-out and training materials apart), log-domain error, ΔE ITP and ΔE 2000 of renders, encode and "
        "decode time. Without a data option it runs on analytic materials the project generates itself.",
    )
    source = report.add_mutually_exclusive_group()
    source.add_argument("--dataset", type=Path, help="a dataset file with full tables (bvae dataset build)")
    source.add_argument("--nbrdf-zip", type=Path, help="build the NBRDF proxy dataset first (about a minute)")
    source.add_argument("--analytic", type=int, default=12, metavar="N",
                        help="analytic presets plus N random materials (default source; N=12)")
    report.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    report.add_argument("--pca", default="8,16,32", help="PCA sizes (default 8,16,32)")
    report.add_argument("--model", action="append", default=[], metavar="DIR",
                        help="another trained model folder to report beside the shipped one (repeatable)")
    report.add_argument("--limit", type=int, help="only the first N materials (a quick look)")
    report.add_argument("--quiet", action="store_true", help="no progress bar")
    report.set_defaults(handler=run_report)
    rd = ops.add_parser(
        "rd",
        help="rate–distortion on held-out materials in file bytes, against PCA fitted on the same materials",
        description="Run the experiments of a configuration file (JSON: dataset, experiments of model folder "
        "and label, budgets): encode each model's held-out materials per family with --bytes N into one "
        "library, count the file's bytes less the names, and compare the mean mapped RelAE with PCA of the "
        "same training materials in N bytes: int8 or float16 coefficients, transform-coded (bits by reverse "
        "water-filling, a gain byte) and entropy-coded (range coder, priors of the training spread). Writes "
        "one row per point (schema brdfcodec.rows/1, with the "
        "commit) as JSON Lines and prints the summary table.",
    )
    rd.add_argument("--config", type=Path, required=True, help="runner configuration (JSON)")
    rd.add_argument("-o", "--output", type=Path, required=True, help="rows to write (.jsonl)")
    rd.add_argument("--budgets", type=_budget_list, metavar="N,N,...",
                    help="only these size budgets (bytes per material), in place of the configuration's: a "
                    "quicker look at some cells; the rows say which budgets they hold")
    rd.add_argument("--quiet", action="store_true", help="no progress lines")
    rd.set_defaults(handler=run_rd)
    table = ops.add_parser("table", help="print the summary table of result rows (.jsonl files)",
                           description="Summary tables (Markdown) of rows written by `bvae bench rd`: brdfcodec "
                           "against the best of every PCA variant at each budget (the best int8/float16 PCA "
                           "beside it).")
    table.add_argument("rows", type=Path, nargs="+", help="row files (.jsonl)")
    table.add_argument("-o", "--output", type=Path, help="also write the table to this Markdown file")
    table.add_argument("--plot", type=Path, help="also draw the rate–distortion panels (PNG), one per family")
    table.add_argument("--time-plot", type=Path,
                       help="also draw error against decode time, every point (PNG), one panel per family")
    table.add_argument("--results-table", type=Path,
                       help="also write one Markdown table, a line per group, family and budget naming the model's "
                       "decoder hash and the commit (the Results page's table)")
    table.set_defaults(handler=run_table)
    from brdfcodec.cli.fuzz_campaign import register_fuzz

    register_fuzz(ops)  # bvae bench fuzz (issue 49)


def _budget_list(text: str) -> tuple[int, ...]:
    """``--budgets 32,64``: positive integers, comma-separated."""
    try:
        budgets = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected positive integers separated by commas, got {text!r}") from None
    if not budgets or min(budgets) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers separated by commas, got {text!r}")
    return budgets


def run_rd(args: argparse.Namespace) -> int:
    """Run a rate–distortion configuration, write its rows, print the summary."""
    import dataclasses

    from brdfcodec.report.generalisation import load_config, run_config
    from brdfcodec.report.rows import current_commit, stamp, summary_markdown, write_rows

    config = load_config(args.config)
    if args.budgets is not None:
        config = dataclasses.replace(config, budgets=args.budgets)
    start = time.perf_counter()
    measured = current_commit()  # the checkout the run loaded, not the one when its rows are written (an hour on)
    rows = run_config(config, progress=None if args.quiet else lambda line: print(line, flush=True))
    rows = stamp(rows, study="rd", config=str(args.config), dataset=str(config.dataset), commit=measured)
    write_rows(args.output, rows)
    print(summary_markdown(rows))
    print(f"wrote {args.output} ({len(rows)} rows) in {time.perf_counter() - start:.0f} s")
    return 0


def run_table(args: argparse.Namespace) -> int:
    """Print (and optionally write) the summary table of row files."""
    from brdfcodec.io.atomic import atomic_output
    from brdfcodec.report.rows import rd_plot, read_rows, summary_markdown

    rows = [row for path in args.rows for row in read_rows(path)]
    text = summary_markdown(rows)
    if args.plot is not None:
        rd_plot(rows, args.plot)
    if args.time_plot is not None:
        from brdfcodec.report.rd_markdown import write_decode_time_plot

        write_decode_time_plot(rows, args.time_plot)
    if args.results_table is not None:
        from brdfcodec.report.rd_markdown import results_table

        with atomic_output(args.results_table, overwrite=True) as tmp:
            Path(tmp).write_text(results_table(rows), encoding="utf-8")
    if args.output is not None:
        with atomic_output(args.output, overwrite=True) as tmp:
            Path(tmp).write_text(text + "\n", encoding="utf-8")
    print(text)
    return 0


def run_report(args: argparse.Namespace) -> int:
    """Build the data if needed, evaluate, write the report."""
    from brdfcodec.datasets.hdf5 import build_dataset
    from brdfcodec.datasets.sources import analytic_sources, nbrdf_zip_sources
    from brdfcodec.report.evaluate import evaluate_dataset, summarise
    from brdfcodec.report.output import markdown_table, write_report

    pca_sizes = [int(v) for v in args.pca.split(",") if v.strip()]
    if any(k < 1 for k in pca_sizes):
        raise ValueError("--pca sizes must be ≥ 1")
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bvae-report-") as scratch:
        dataset = args.dataset
        if dataset is None:
            dataset = Path(scratch) / "data.h5"
            if args.nbrdf_zip is not None:
                from brdfcodec.datasets.nbrdf import NBRDF_SOURCE_KIND

                sources = nbrdf_zip_sources(args.nbrdf_zip)
                kind, description = NBRDF_SOURCE_KIND, "NBRDF proxy of MERL (90 neural fits on the MERL grid)"
            else:
                sources = analytic_sources(random_count=args.analytic, seed=0)
                kind, description = "analytic", "analytic Lambert + GGX BRDFs generated by brdfcodec"
            build_dataset(dataset, sources, source_kind=kind, description=description, progress=not args.quiet)
        points, rows, data = evaluate_dataset(dataset, pca_sizes=pca_sizes, extra_models=args.model,
                                              limit=args.limit, progress=not args.quiet)
        records = summarise(points, rows, data)
    written = write_report(args.output, records, rows)
    print(markdown_table(records))
    print(f"wrote {', '.join(str(p) for p in written)} in {time.perf_counter() - start:.0f} s")
    return 0
