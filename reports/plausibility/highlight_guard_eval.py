"""Issue 50, item 1: inverted highlights of latent traversals with and without the highlight guard, and its cost.

For each material (encoded with the shipped model), every latent dimension is traversed by
:func:`brdfcodec.edit.latent_edits.traverse` at the given offsets (prior σ), as ``bvae edit traverse`` does. Each
edit is judged as issue 50's reviewer did (:func:`brdfcodec.edit.plausibility.inverted_highlights`: a column whose
peak at θh < 2° is darker than half its body at θh 40–60° where the unedited decode's is not), on the tables at
the kept φd bins (exactly the decoded slices, unmapped; the energy bound's factor does not change the ratio),
once as the network decodes it and once after the guard (:mod:`brdfcodec.representation.highlight_guard`) with
each (window, τ) asked for. The cost of the guard is the change it makes to the edits' mapped slices (entries
above the horizon), and what it would change on the unedited decodes (where it is not applied).
With ``--full``, the ±3σ edits are judged again on full 180-bin tables: before, the unguarded table with the
energy bound; after, :meth:`BrdfDecoder.decode` of the edited record (the normative path).

Run from the repository root::

    nice python reports/plausibility/highlight_guard_eval.py --family merl --count 10 \\
        --out reports/plausibility/highlight-guard.jsonl
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.conventions import KEPT_PHI_D_SLICES, N_CHANNELS
from brdfcodec.edit.latent_edits import traverse
from brdfcodec.edit.plausibility import entry_valid_mask, inverted_highlights
from brdfcodec.report.rows import read_rows, stamp, write_rows
from brdfcodec.representation import table_from_mapped
from brdfcodec.representation.energy import energy_bound_scale_mapped
from brdfcodec.representation.highlight_guard import GUARD_THETA_H_BINS, GUARD_TOLERANCE, guard_highlight


def _records(family: str, count: int, encoder: BrdfEncoder, dataset: Path) -> list:
    """Encoded records: ``merl`` — the dataset's first ``count`` MERL-family materials of its validation split
    (NBRDF proxies of MERL; the shipped model was trained on all 120, so they are not held out); ``analytic`` —
    ``count`` random Lambert + GGX materials (seed 50), never seen in training."""
    if family == "merl":
        import h5py

        with h5py.File(dataset, "r") as f:
            fam = f["families"][:].astype(str)
            split = f["split"][:].astype(str)
            idx = [int(i) for i in np.flatnonzero((fam == "merl") & (split == "validation"))[:count]]
            names = [str(f["names"][i].decode()) for i in idx]
            inputs = np.stack([f["inputs"][i] for i in idx])
            masks = np.stack([f["input_masks"][i] for i in idx])
        return encoder.encode_arrays(names, inputs, masks, [None] * len(names))
    from brdfcodec.datasets.analytic import random_analytic_materials

    return [encoder.encode(m.to_merl(), name=m.name) for m in random_analytic_materials(count, seed=50)]


def _kept(mapped: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        return table_from_mapped(mapped, phi_d_bins=KEPT_PHI_D_SLICES)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", choices=("merl", "analytic"), required=True)
    parser.add_argument("--count", type=int, default=10)
    parser.add_argument("--steps", default="-3,-2,-1,1,2,3")
    parser.add_argument("--guards", default=f"{GUARD_THETA_H_BINS}:{GUARD_TOLERANCE},21:0.05,30:0,30:0.1",
                        help="window:tolerance pairs to measure, comma-separated (the first is the normative one)")
    parser.add_argument("--dataset", type=Path, default=Path("runs/both.h5"))
    parser.add_argument("--full", action="store_true", help="also judge the ±3σ edits on full tables (slow)")
    parser.add_argument("--out", type=Path, required=True, help="JSON Lines rows (appended to)")
    args = parser.parse_args(argv)
    command = "nice python reports/plausibility/highlight_guard_eval.py " + " ".join(
        shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    steps = [float(s) for s in args.steps.split(",")]
    guards = [(int(w), float(t)) for w, t in (g.split(":") for g in args.guards.split(","))]

    t0 = time.time()
    encoder = BrdfEncoder()
    decoder = encoder.decoder
    records = _records(args.family, args.count, encoder, args.dataset)
    valid = np.tile(entry_valid_mask(), (N_CHANNELS, 1, 1))  # (63, 90, 90): entries above the horizon
    variants = ["none", *(f"{w}:{t:g}" for w, t in guards)]
    flags: dict[str, list[np.ndarray]] = {v: [] for v in variants}
    three: list[np.ndarray] = []  # which decodes are at ±3σ
    change: dict[str, list[np.ndarray]] = {v: [] for v in variants[1:]}
    source_change: dict[str, list[float]] = {v: [] for v in variants[1:]}
    full_before: list[bool] = []
    full_after: list[bool] = []
    for record in records:
        source = decoder.decode_mapped(np.asarray(record.mu, dtype=np.float32)[None])[0]
        src_table = _kept(source)
        edits = [e for d in range(decoder.latent_dim) for e in traverse(record, d, steps)]
        offsets = np.array([e.meta["edit"]["value"] for e in edits])
        three.append(np.abs(offsets) == 3)
        mapped = decoder.decode_mapped(np.stack([e.mu for e in edits]))
        flags["none"].append(inverted_highlights(src_table, _kept(mapped)).reshape(len(edits), -1).any(axis=1))
        for (w, t), name in zip(guards, variants[1:], strict=True):
            guarded = guard_highlight(mapped, window=w, tolerance=t)
            flags[name].append(inverted_highlights(src_table, _kept(guarded)).reshape(len(edits), -1).any(axis=1))
            diff = np.abs(guarded - mapped)[:, valid]
            change[name].append(np.stack([diff.mean(axis=1), np.sqrt((diff**2).mean(axis=1)), diff.max(axis=1)], 1))
            source_change[name].append(float(np.abs(guard_highlight(source, window=w, tolerance=t) - source)[valid]
                                             .mean()))
        if args.full:
            for e, m, is3 in zip(edits, mapped, three[-1], strict=True):
                if not is3:
                    continue
                src_full = table_from_mapped(source)
                before = table_from_mapped(m, scale=energy_bound_scale_mapped(m))
                after = decoder.decode(e, masked="keep")
                full_before.append(bool(inverted_highlights(src_full, before).any()))
                full_after.append(bool(inverted_highlights(src_full, after).any()))
        print(f"{record.name}: {time.time() - t0:.0f} s", file=sys.stderr)

    is3 = np.concatenate(three)
    rows = []
    for name in variants:
        f = np.concatenate(flags[name])
        row = {"family": {"merl": "NBRDF proxy of MERL (validation split; seen in training)",
                          "analytic": "analytic Lambert+GGX (random, seed 50; never seen)"}[args.family],
               "materials": [r.name for r in records], "model": decoder.reference.name,
               "decoder_sha256": decoder.reference.sha256, "steps": steps,
               "guard": name, "normative_guard": f"{GUARD_THETA_H_BINS}:{GUARD_TOLERANCE:g}",
               "judge": "issue 50: peak (max, θh<2°, bins 0-13) < 0.5 × body (mean, θh 40-60°, bins 60-73) in some "
                        "column (colour, θd, kept φd bin) where the unedited decode's is not",
               "decodes": int(f.size), "inverted": int(f.sum()), "inverted_rate": float(f.mean()),
               "decodes_3sigma": int(is3.sum()), "inverted_3sigma": int(f[is3].sum()),
               "inverted_rate_3sigma": float(f[is3].mean()), "command": command}
        if name != "none":
            c = np.concatenate(change[name])
            row.update({"mapped_change_mean": float(c[:, 0].mean()), "mapped_change_rms": float(c[:, 1].mean()),
                        "mapped_change_max": float(c[:, 2].max()),
                        "decodes_changed": float((c[:, 2] > 0).mean()),
                        "source_change_mean_if_applied": float(np.mean(source_change[name]))})
        rows.append(row)
    if args.full:
        rows.append({**rows[0], "guard": "none", "tables": "full 180 bins, energy bound",
                     "decodes": len(full_before), "inverted": int(sum(full_before)),
                     "inverted_rate": float(np.mean(full_before))})
        rows.append({**rows[1], "guard": variants[1], "tables": "full 180 bins, BrdfDecoder.decode (normative)",
                     "decodes": len(full_after), "inverted": int(sum(full_after)),
                     "inverted_rate": float(np.mean(full_after))})
    stamped = stamp(rows, study="highlight-guard")
    previous = read_rows(args.out) if args.out.exists() else []
    write_rows(args.out, [*previous, *stamped])
    for row in rows:
        print({k: v for k, v in row.items() if k not in ("materials", "judge", "command")})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
