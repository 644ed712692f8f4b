"""Why a layered decode stays above 1.5× a base-only one: the basis sum is memory-bound (issue 14).

Usage::

    python benchmarks/basis_sum_study.py [-o reports/rd-study/basis-sum.json]

On the analytic ``gold`` material encoded at 16 KB (75 basis coefficients
and a detail layer, the ``decode-layered`` benchmark's record), times (median
and minimum of 30 calls, milliseconds) of: the whole table decoded base-only
and layered; the layers alone as the decoder computes them; the basis sum
``c @ B`` of the shipped basis in float32 with numpy's BLAS on one thread
and on all, and with torch in float32, float16 and bfloat16; and the basis
sum split between the main thread and the detail layer's thread (the share
of the sum the main thread does). Run it on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from brdfcodec.analytic import ANALYTIC_PRESETS
from brdfcodec.blas_threads import single_blas_thread
from brdfcodec.codec import BrdfEncoder
from brdfcodec.layers.detail import decode_detail

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
    vectors = basis.components[record.basis.first : record.basis.first + len(c)].astype(np.float32)
    rows: dict[str, Any] = {
        "coefficients": len(c), "basis_entries": int(vectors.shape[1]),
        "basis_megabytes_float32": vectors.nbytes / 1e6,
        "table base-only": timed(lambda: decoder.table(record.base())),
        "table layered": timed(lambda: decoder.table(record)),
    }
    with single_blas_thread():
        rows["layers (decoder)"] = timed(lambda: decoder._layer_residuals(record))
        rows["basis sum numpy, 1 BLAS thread"] = timed(lambda: c @ vectors)
    rows["basis sum numpy, all BLAS threads"] = timed(lambda: c @ vectors)
    for dtype in (torch.float32, torch.float16, torch.bfloat16):
        tv, tc = torch.from_numpy(vectors).to(dtype), torch.from_numpy(c).to(dtype)
        rows[f"basis sum torch {str(dtype).removeprefix('torch.')}"] = timed(lambda tv=tv, tc=tc: tc @ tv)

    def split(share: float) -> Callable[[], None]:
        cut = int(vectors.shape[1] * share)

        def run() -> None:
            out = np.empty(vectors.shape[1], dtype=np.float32)

            def detail_then_tail() -> None:
                decode_detail(record.detail)
                np.matmul(c, vectors[:, cut:], out=out[cut:])

            thread = threading.Thread(target=detail_then_tail)
            thread.start()
            np.matmul(c, vectors[:, :cut], out=out[:cut])
            thread.join()

        return run

    with single_blas_thread():
        for share in (1.0, 0.8, 0.6):
            rows[f"basis sum {share:.0%} on the main thread, rest after the detail layer"] = timed(split(share))
    rows["layered / base-only (medians)"] = rows["table layered"]["median_ms"] / rows["table base-only"]["median_ms"]
    for key, value in rows.items():
        print(key, value, flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"material": "analytic gold, 16 KB record, effort 0",
                                       "torch_threads": torch.get_num_threads(), "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
