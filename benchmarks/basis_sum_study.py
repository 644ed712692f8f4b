"""Where a layered decode's time goes, against a base-only decode (issue 14's 1.5× target).

Usage::

    python benchmarks/basis_sum_study.py [-o reports/rd-study/basis-sum.json]

On the analytic ``gold`` material encoded at 16 KB (32 basis coefficients
and a detail layer, the ``decode-layered`` benchmark's record), times (median
and minimum of 30 calls, milliseconds) of: the whole table decoded base-only;
the mapped clamp of the network output, the decoder's and the one before it;
layered as the decoder does it (the network on every core, then the layers
on the calling thread); layered with the layers first and the network
after; the layers alone (basis sum, then detail layer, one thread); the
detail layer alone, inverted plane by plane over its nonzero blocks (the
decoder's choice here) and batched over all planes; and the basis sum
``c @ B`` of the shipped basis in float32 with numpy's BLAS on one thread and
on all, and with torch in float32, float16 and bfloat16, against the
decoder's sum over the factors of the shipped (factorised) basis. The
dense basis sum reads 116 MB per decode and is bound by memory bandwidth;
the factors are 33 MB; the detail layer and the network are bound by
compute. Run it on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from basis_study import replaced

from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.runtime.threads import single_blas_thread
from brdfcodec.codec import BrdfEncoder
from brdfcodec.conventions import MAPPED_MAX
from brdfcodec.layers import detail as detail_module
from brdfcodec.layers.detail import decode_detail
from brdfcodec.representation import clamp_mapped, table_from_mapped

CALLS = 30


def timed(function: Callable[[], Any]) -> dict[str, float]:
    """Median and minimum wall time of :data:`CALLS` calls after one warm-up, in milliseconds."""
    function()
    times = []
    for _ in range(CALLS):
        start = time.perf_counter()
        function()
        times.append(1000 * (time.perf_counter() - start))
    return {"median_ms": float(np.median(times)), "min_ms": float(np.min(times))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=Path("reports/rd-study/basis-sum.json"))
    args = parser.parse_args()
    record = BrdfEncoder(effort=0, bytes=16384).encode(ANALYTIC_PRESETS["gold"].to_merl(), name="gold")
    decoder = BrdfEncoder().decoder
    decoder.table(record)  # loads the shared basis
    basis = decoder.shared_basis
    assert record.basis is not None and record.detail is not None and basis is not None
    c = record.basis.coefficients()
    vectors = basis.vectors(record.basis.first, len(c))
    rows: dict[str, Any] = {
        "coefficients": len(c), "basis_entries": int(vectors.shape[1]),
        "basis_megabytes_float32": vectors.nbytes / 1e6,
        "table base-only": timed(lambda: decoder.table(record.base())),
        "table layered (decoder: network, then layers)": timed(lambda: decoder.table(record)),
    }

    def one_after_the_other() -> None:
        residuals = decoder._layer_residuals(record)
        mapped = decoder.decode_mapped(record.mu)
        for residual in residuals:
            mapped += residual
        table_from_mapped(clamp_mapped(mapped, out=mapped))

    with single_blas_thread():
        rows["table layered, layers then network"] = timed(one_after_the_other)
        rows["layers (one thread: basis sum, then detail layer)"] = timed(lambda: decoder._layer_residuals(record))
        network_output = decoder.decode_mapped(record.mu) * np.float32(1.2) - np.float32(0.1)  # some entries out
        rows["clamp of the network output (decoder)"] = timed(lambda: clamp_mapped(network_output.copy()))
        rows["clamp, clip with Python float bounds then nan_to_num (before)"] = timed(
            lambda: np.nan_to_num(np.clip(network_output.copy(), 0.0, MAPPED_MAX), copy=False, nan=0.0))
        rows["copy of the network output (in both clamp rows)"] = timed(lambda: network_output.copy())
        rows["detail layer alone (decoder: nonzero blocks)"] = timed(lambda: decode_detail(record.detail))
        with replaced(detail_module, "_DENSE_SHARE", 0.0):
            rows["detail layer alone, batched over all planes"] = timed(lambda: decode_detail(record.detail))
        rows["basis sum numpy, 1 BLAS thread"] = timed(lambda: c @ vectors)
        if basis.factorised is not None:  # what the decoder does with a factorised basis (spec/model.md 1.4)
            rows["basis sum on the factors (decoder), 1 thread"] = timed(
                lambda: basis.weighted_sum(c, record.basis.first))
    rows["basis sum numpy, all BLAS threads"] = timed(lambda: c @ vectors)
    for dtype in (torch.float32, torch.float16, torch.bfloat16):
        tv, tc = torch.from_numpy(vectors).to(dtype), torch.from_numpy(c).to(dtype)
        rows[f"basis sum torch {str(dtype).removeprefix('torch.')}"] = timed(lambda tv=tv, tc=tc: tc @ tv)
    base = rows["table base-only"]["median_ms"]
    layered = rows["table layered (decoder: network, then layers)"]["median_ms"]
    rows["layered / base-only (medians)"] = layered / base
    rows["layers then network / base-only (medians)"] = rows["table layered, layers then network"]["median_ms"] / base
    for key, value in rows.items():
        print(key, value, flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"material": "analytic gold, 16 KB record, effort 0",
                                       "torch_threads": torch.get_num_threads(), "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
