"""Fit a record's μ and basis coefficients on the full table's error instead of the kept slices' (issue 14).

Usage::

    python benchmarks/full_table_fit_study.py DATASET.h5 [-o reports/rd-study/full-table-fit.json]

The encoder fits μ and the basis coefficients together on the mapped L1
error of the 21 kept φd slices (:func:`brdfcodec.codec.refine.fit_basis_coefficients`),
but the report measures the full table: the 180 φd bins interpolated from
them. This runs the encoder's own rate control (``--bytes`` 32 and 64,
float16, effort 1) on the dataset's held-out materials twice — with the
kept-slice objective, and with the mapped L1 error of the interpolated
full table over the source's valid entries — and measures each record's
full-table mapped RelAE as the report does (:func:`brdfcodec.codec.measure`).
"""

from __future__ import annotations

import functools
import json
import time

import numpy as np
import torch
from basis_study import held_out_materials, replaced, study_arguments

import brdfcodec.codec.encoding as encoding
from brdfcodec.codec import BrdfEncoder, measure
from brdfcodec.conventions import MAPPED_MAX, N_KEPT_SLICES, N_PHI_D
from brdfcodec.codec.refine import fit_basis_coefficients
from brdfcodec.representation import map_values
from brdfcodec.representation.layout import interpolation_plan

BUDGETS = (32, 64)
#: For each φd bin: left kept slot, right kept slot, weight of the right one (the decoder's interpolation).
_LEFT, _RIGHT, _WEIGHT = (torch.as_tensor(np.array(a)) for a in interpolation_plan())


def as_fitted(values: np.ndarray) -> torch.Tensor:
    """A full table ``(3, 90, 90, 180)`` as float32 ``(1, 3, 180, 90, 90)`` (colour, φd, θh, θd)."""
    return torch.as_tensor(np.ascontiguousarray(np.moveaxis(np.asarray(values, dtype=np.float32), 3, 1)))[None]


def full_table_l1(decoded: torch.Tensor, target: torch.Tensor, weight: torch.Tensor, *,
                  truth: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Mapped L1 error of the interpolated, clamped full table over the source's valid entries, per material.

    ``truth`` and ``valid``: ``(1, 3, 180, 90, 90)`` (colour, φd, θh, θd); ``target`` and ``weight`` are unused.
    """
    del target, weight
    kept = decoded.view(len(decoded), 3, N_KEPT_SLICES, 90, 90)
    w = _WEIGHT.to(decoded.dtype).view(1, 1, N_PHI_D, 1, 1)
    full = (kept[:, :, _LEFT] * (1 - w) + kept[:, :, _RIGHT] * w).clamp(0.0, MAPPED_MAX)
    return ((full - truth) * valid).abs().flatten(1).sum(1)


def main() -> None:
    args = study_arguments(__doc__, "reports/rd-study/full-table-fit.json")
    start = time.perf_counter()
    held = held_out_materials(args.dataset)
    results: dict[str, dict[str, list[float]]] = {}
    for objective in ("kept-slices", "full-table"):
        for budget in BUDGETS:
            encoder = BrdfEncoder(effort=1, bytes=budget, latent_dtype="float16")
            errors = []
            for i, name in enumerate(held.names):
                table = held.tables[i]
                truth = np.where(table.mask, map_values(np.maximum(table.values, 0.0)), 0.0)
                error = functools.partial(full_table_l1, truth=as_fitted(truth), valid=as_fitted(table.mask))
                fit = functools.partial(fit_basis_coefficients, error=error)
                with replaced(encoding, "fit_basis_coefficients", fit, active=objective == "full-table"):
                    record = encoder.encode_arrays([name], held.inputs[i:i + 1], held.masks[i:i + 1], [table])[0]
                errors.append(measure(record, encoder.decoder, table).meta["relae"]["mapped"])
            results.setdefault(objective, {})[str(budget)] = errors
            print(f"{objective:12} {budget:3d} B: held-out full-table mapped RelAE {np.mean(errors):.5f}", flush=True)
    summary = {objective: {budget: float(np.mean(e)) for budget, e in rows.items()}
               for objective, rows in results.items()}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({
        "dataset": held.description, "held_out": len(held.names), "names": held.names,
        "metric": "full-table mapped RelAE, held-out mean (float16, effort 1, --bytes rate control)",
        "command": f"python benchmarks/full_table_fit_study.py {args.dataset.name}",
        "seconds": time.perf_counter() - start, "mean": summary, "per_material": results,
    }, indent=1) + "\n")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
