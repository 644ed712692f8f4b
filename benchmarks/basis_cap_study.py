"""How many basis coefficients a size budget should spend under a detail layer (issue 14).

Usage::

    python benchmarks/basis_cap_study.py DATASET.h5 [-o reports/rd-study/basis-cap.json]

Encodes the dataset's held-out (validation) materials with the default model
at several size budgets (``BrdfEncoder(bytes=N)``, effort 1, float32 latents) under five
policies for the basis layer — the encoder's own search (all coefficients
that fit, and at most :data:`~brdfcodec.codec.rate.DETAIL_BASIS_COUNT`),
all that fit only, and at most 32, 16 or 0 — and records the mean
full-table mapped RelAE, the mean payload and the coefficient counts used.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

# sibling script: Python puts the running script's folder on sys.path
from basis_study import held_out_materials, study_arguments

import brdfcodec.codec.encoding as encoding
import brdfcodec.codec.rate as rate
from brdfcodec.codec import BrdfEncoder
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.representation.metrics import error_report

BUDGETS = (128, 256, 1024, 4096, 16384)
#: policy → (largest basis count allowed, whether the encoder's smaller second count is tried)
POLICIES: dict[str, tuple[int | None, bool]] = {
    "search": (None, True), "all": (None, False), "at-most-32": (32, False), "at-most-16": (16, False),
    "none": (0, False),
}


@contextmanager
def policy(cap: int | None, search: bool) -> Iterator[None]:
    """Limit the basis size the encoder may use, and switch its second count off."""
    original_layers, original_count = encoding.encode_layers, rate.DETAIL_BASIS_COUNT

    def capped(*args: Any, **kwargs: Any) -> rate.RateResult:
        if cap is not None:
            kwargs["basis_count"] = min(kwargs["basis_count"], cap)
        return original_layers(*args, **kwargs)

    encoding.encode_layers = capped  # type: ignore[assignment]
    if not search:
        rate.DETAIL_BASIS_COUNT = 1 << 30  # type: ignore[misc]
    try:
        yield
    finally:
        encoding.encode_layers = original_layers  # type: ignore[assignment]
        rate.DETAIL_BASIS_COUNT = original_count  # type: ignore[misc]


def main() -> None:
    args = study_arguments(__doc__, "reports/rd-study/basis-cap.json")
    start = time.perf_counter()
    held = held_out_materials(args.dataset)
    x, m, tables, names, description = held.inputs, held.masks, held.tables, held.names, held.description
    rows: list[dict[str, Any]] = []
    for budget in BUDGETS:
        for label, (cap, search) in POLICIES.items():
            with policy(cap, search):
                encoder = BrdfEncoder(bytes=budget)
                records = encoder.encode_arrays(names, x, m, tables)
            errors = [error_report(t.values, encoder.decoder.decode(r, masked="keep").astype(np.float64),
                                   t.mask).relae_mapped.overall for r, t in zip(records, tables, strict=True)]
            counts = [r.basis.count if isinstance(r, LayeredRecord) and r.basis is not None else 0 for r in records]
            row = {"budget": budget, "policy": label, "relae_mapped_mean": float(np.mean(errors)),
                   "payload_bytes_mean": float(np.mean([r.meta["rate"]["payload_bytes"] for r in records])),
                   "basis_counts": sorted(set(counts))}
            rows.append(row)
            print(json.dumps(row), flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"data": description, "materials": names, "effort": 1, "rows": rows,
                                       "seconds": time.perf_counter() - start}, indent=1) + "\n")


if __name__ == "__main__":
    main()
