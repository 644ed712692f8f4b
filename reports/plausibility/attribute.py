"""Which part of the decoder makes traversal decodes implausible, and what a decode-time fix would change.

Run from the repository root (about 3 minutes on one core)::

    OMP_NUM_THREADS=1 python reports/plausibility/attribute.py > reports/plausibility/attribute.json

Data: the shipped example library (90 materials of the NBRDF proxy of MERL,
encoded with the default model), every dimension, t in ±1, ±2, ±3 σ.

For a linear-basis decoder the unclamped output is ``u(z) = linear(z) +
correction(z)`` with ``linear(z) = mean + z · components`` exactly affine, so
the traversal ``z = μ + t·e_d`` splits into

- ``linear only``: ``clamp(u(μ) + t · components[d])`` (correction frozen at μ);
- ``correction only``: ``clamp(u(μ + t e_d) − t · components[d])`` (linear path frozen at μ);
- ``as decoded``: ``clamp(u(μ + t e_d))``, what ``BrdfDecoder.decode_mapped`` returns.

It also evaluates two decode-time variants that leave μ untouched (t = 0 is
never rewritten, so records decode bit-identically):

- ``log-ratio``: apply the traversal's change Δ = u(μ + t e_d) − u(μ) to log ρ
  instead of to the mapped value log1p(ρ/ε)/L, i.e. ρ' = ρ(μ)·exp(L·Δ): it
  never reaches the floor, so it cannot make holes;
- ``plausible range``: stop a traversal at the last step before the first
  implausible one (what an editor could do), reported as the fraction of
  (material, dimension, sign) whose first step (±1σ) is already implausible.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import torch

from brdfcodec.codec import BrdfDecoder, MaterialLibrary
from brdfcodec.conventions import MAPPED_MAX
from brdfcodec.edit.plausibility import DEFAULT_STEPS, inverted_cells, new_holes
from brdfcodec.examples import example_library
from brdfcodec.models.output_paths import decompose_output
from brdfcodec.representation.mapping import LOG_RANGE


def _components(decoder: BrdfDecoder) -> np.ndarray:
    """Linear-path components scattered to the network layout, (latent_dim, 63, 90, 90)."""
    net = decoder.network
    dense = torch.zeros(decoder.latent_dim, 63 * 90 * 90)
    dense[:, net.valid_index] = net.basis_components.float()
    return dense.view(decoder.latent_dim, 63, 90, 90).numpy()


def main() -> int:
    decoder = BrdfDecoder()
    with MaterialLibrary(example_library(), decoder=decoder) as library:
        records = [library.record(name) for name in library.names]
    comps = _components(decoder)
    steps = np.asarray(DEFAULT_STEPS, dtype=np.float32)
    dims = decoder.latent_dim
    variants = ("as decoded", "linear only", "correction only", "log-ratio")
    inverted = {v: np.zeros((dims, steps.size)) for v in variants}
    holes = {v: np.zeros((dims, steps.size)) for v in variants}
    first_bad = np.zeros((dims, 2))  # (dim, sign −/+): first step already inverted or holed
    for record in records:
        mu = np.asarray(record.mu, dtype=np.float32)
        lin0, cor0 = decompose_output(decoder, mu[None])
        raw0 = (lin0 + cor0)[0]
        source = np.clip(raw0, 0, MAPPED_MAX)
        source_inv = inverted_cells(source)
        codes = np.stack([mu + t * np.eye(dims, dtype=np.float32)[d] for d in range(dims) for t in steps])
        lin, cor = decompose_output(decoder, codes)
        raw = (lin + cor).reshape(dims, steps.size, *raw0.shape)
        shift = steps[None, :, None, None, None] * comps[:, None]
        delta = raw - raw0
        with np.errstate(over="ignore"):
            log_ratio = np.log1p(np.expm1(source * LOG_RANGE) * np.exp(np.minimum(delta * LOG_RANGE, 80))) / LOG_RANGE
        decodes = {
            "as decoded": np.clip(raw, 0, MAPPED_MAX),
            "linear only": np.clip(raw0 + shift, 0, MAPPED_MAX),
            "correction only": np.clip(raw - shift, 0, MAPPED_MAX),
            "log-ratio": np.clip(log_ratio, 0, MAPPED_MAX),
        }
        for name, mapped in decodes.items():
            inv = (inverted_cells(mapped) & ~source_inv).reshape(dims, steps.size, -1).any(-1)
            hole = new_holes(source, mapped).reshape(dims, steps.size, -1).any(-1)
            inverted[name] += inv
            holes[name] += hole
            if name == "as decoded":
                bad = inv | hole
                first_bad[:, 0] += bad[:, list(steps).index(-1.0)]
                first_bad[:, 1] += bad[:, list(steps).index(1.0)]
    n = len(records)
    summary = {
        "data": "shipped example library: 90 materials of the NBRDF proxy of MERL, default model",
        "steps": steps.tolist(),
        "inverted": {v: (inverted[v] / n).round(4).tolist() for v in variants},
        "holes": {v: (holes[v] / n).round(4).tolist() for v in variants},
        "inverted_mean": {v: round(float(inverted[v].mean() / n), 4) for v in variants},
        "holes_mean": {v: round(float(holes[v].mean() / n), 4) for v in variants},
        "implausible_at_first_step": {"minus": (first_bad[:, 0] / n).round(4).tolist(),
                                      "plus": (first_bad[:, 1] / n).round(4).tolist()},
    }
    json.dump(summary, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
