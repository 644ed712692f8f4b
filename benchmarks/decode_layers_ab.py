"""Interleaved A/B of a layered decode: layers summed after the network on one thread, against the decoder's own path.

Usage::

    python benchmarks/decode_layers_ab.py [--rounds 200]

The analytic ``gold`` material, encoded with ``--bytes 16384`` (75 basis
coefficients and a detail layer), is decoded base-only, the old way and the
current way, in turn, ``rounds`` times; medians in ms are printed. The two
layered paths must give identical tables. Interleaving keeps a noisy machine's
drift out of the comparison (see ``benchmarks/README.md``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from brdfcodec.analytic import ANALYTIC_PRESETS
from brdfcodec.blas_threads import single_blas_thread
from brdfcodec.codec import BrdfDecoder, BrdfEncoder, _apply_mask
from brdfcodec.layers.detail import decode_detail
from brdfcodec.representation import clamp_mapped, table_from_mapped


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=200)
    args = parser.parse_args()
    record = BrdfEncoder(effort=0, bytes=16384).encode(ANALYTIC_PRESETS["gold"].to_merl(), name="gold")
    decoder = BrdfDecoder()
    decoder.decode(record)  # loads the shared basis
    basis, base = decoder.shared_basis, record.base()

    def layers_after_the_network() -> np.ndarray:
        with single_blas_thread():
            mapped = decoder.decode_mapped(record.mu)
            mapped += basis.residual(record.basis.coefficients(), record.basis.first)
            mapped += decode_detail(record.detail).reshape(mapped.shape)
            return _apply_mask(table_from_mapped(clamp_mapped(mapped, out=mapped)), None, "unmeasured")

    current = "decoder (layers first, detail on a second thread)"
    paths = {"base only": lambda: decoder.decode(base), "layers after the network": layers_after_the_network,
             current: lambda: decoder.decode(record)}
    if not np.array_equal(paths["layers after the network"](), paths[current]()):
        raise SystemExit("the two layered paths disagree")
    times: dict[str, list[float]] = {label: [] for label in paths}
    for _ in range(args.rounds):
        for label, decode in paths.items():
            start = time.perf_counter()
            decode()
            times[label].append(time.perf_counter() - start)
    for label, values in times.items():
        print(f"{label:>52}: {np.median(values) * 1e3:6.2f} ms")


if __name__ == "__main__":
    main()
