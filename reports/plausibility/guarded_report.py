"""Issue 50, item 1: the project's plausibility report (``brdfcodec.edit.plausibility.measure_plausibility``), with
the judge's window (``inverted_wide``), on the materials of ``highlight_guard_eval.py``, without and with the
highlight guard of edited records (``spec/bvae-format.md`` §6 step 6); both with the energy bound, as edits decode.

Run from the repository root::

    nice python reports/plausibility/guarded_report.py --family merl --count 10
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from brdfcodec.codec import BrdfEncoder
from brdfcodec.edit.plausibility import measure_plausibility

sys.path.insert(0, str(Path(__file__).resolve().parent))
from highlight_guard_eval import _records  # noqa: E402 - the same materials


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", choices=("merl", "analytic"), required=True)
    parser.add_argument("--count", type=int, default=10)
    parser.add_argument("--dataset", type=Path, default=Path("runs/both.h5"))
    parser.add_argument("--folder", type=Path, default=Path("reports/plausibility"))
    args = parser.parse_args(argv)
    command = "nice python reports/plausibility/guarded_report.py " + " ".join(
        shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    encoder = BrdfEncoder()
    decoder = encoder.decoder
    records = _records(args.family, args.count, encoder, args.dataset)
    what = {"merl": "NBRDF proxies of MERL, validation split of runs/both.h5 (seen in training by the shipped model)",
            "analytic": "random analytic Lambert + GGX materials, seed 50 (never seen)"}[args.family]
    for guard in (False, True):
        report = measure_plausibility(decoder, records, highlight_guard=guard)
        name = f"guard-{'on' if guard else 'off'}-{args.family}.txt"
        text = (f"# {command}\n# {what}; {decoder.reference.name}\n"
                f"{report.format_table()}\n")
        (args.folder / name).write_text(text, encoding="utf-8")
        wide = report.fractions["inverted_wide"]
        print(f"{name}: inverted_wide {float(wide.mean()):.4f} (±3σ {float(wide[:, [0, -1]].mean()):.4f}), "
              f"inverted {float(report.fractions['inverted'].mean()):.4f}, "
              f"pits {float(report.fractions['pits'].mean()):.4f}, any {float(report.fractions['any'].mean()):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
