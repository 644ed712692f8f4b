"""Issue 50, item 1: the judge's inverted-highlight rate two ways, without and with the highlight guard.

``strict``: :func:`brdfcodec.edit.plausibility.inverted_highlights` — a decode is inverted when some column
(colour, θd bin, kept φd bin) has its peak (largest value, θh < 2°) below half its body (mean, θh 40–60°) where the
unedited decode's column does not. ``agg``: per colour, the mean peak over all columns against half the mean body
over all columns (the reading that reproduces the reviewer's 8.75 % on ±3σ most closely: 8.1 % here). Judged on the
tables at the kept φd bins; ``on`` is after the guard of ``spec/bvae-format.md`` §6 step 6 (the energy bound's
factor does not change either ratio). Materials as in ``highlight_guard_eval.py``.

    nice python reports/plausibility/judge_variants.py merl >> reports/plausibility/judge-variants.txt
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from highlight_guard_eval import _kept, _records  # noqa: E402
from brdfcodec.codec import BrdfEncoder  # noqa: E402
from brdfcodec.edit.latent_edits import traverse  # noqa: E402
from brdfcodec.edit.plausibility import inverted_highlights, peak_body  # noqa: E402
from brdfcodec.representation.highlight_guard import guard_highlight  # noqa: E402
enc = BrdfEncoder(); dec = enc.decoder
fam = sys.argv[1]
recs = _records(fam, 10, enc, Path("runs/both.h5"))
out = {k: [] for k in ("strict-off", "strict-on", "agg-off", "agg-on")}


def m(x: np.ndarray) -> np.ndarray:
    return np.nanmean(x.reshape(*x.shape[:-2], -1), axis=-1)


for r in recs:
    src = _kept(dec.decode_mapped(r.mu[None])[0]); sp, sb = peak_body(src)
    edits = [e for d in range(8) for e in traverse(r, d, [-3.0, -2.0, -1.0, 1.0, 2.0, 3.0])]
    raw = dec.decode_mapped(np.stack([e.mu for e in edits]))
    for tag, mapped in (("off", raw), ("on", guard_highlight(raw))):
        tabs = _kept(mapped)
        out["strict-" + tag].append(inverted_highlights(src, tabs).reshape(len(edits), -1).any(1))
        p, b = peak_body(tabs)
        out["agg-" + tag].append(((m(p) < 0.5 * m(b)) & ~(m(sp) < 0.5 * m(sb))).any(1))
three = np.concatenate([np.abs([e.meta["edit"]["value"] for e in edits]) == 3] * len(recs))
for k, v in out.items():
    v = np.concatenate(v)
    print(f"{fam} {k}: all {int(v.sum())}/{v.size} = {v.mean():.4f}; ±3σ {int(v[three].sum())}/{three.sum()} = {v[three].mean():.4f}")
