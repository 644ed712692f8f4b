"""Interleaved A/B of a layered decode: the decoder's path (layers after the network) against the layers beside it.

Usage::

    python benchmarks/decode_layers_ab.py [--rounds 200] [--bytes 16384] [--latent-dtype float32]

The analytic ``gold`` material, encoded with ``--bytes 16384`` (32 basis
coefficients and a detail layer; ``--bytes 64 --latent-dtype float16`` is
the ``decode-layered-64B`` benchmark's record, basis coefficients only; the
base never projected, ``--project-base never``), is
decoded base-only, the decoder's way (the network on every core, then the
layers on the calling thread), and with the layers on a thread of their own
beside the network, which runs on one torch thread fewer (the decoder's way
before this was measured), in turn, ``rounds`` times, each after a base-only
decode as in the benchmark. Printed: the median time of each, in ms, and the
median over rounds of each layered time divided by the same round's base-only
time. The two layered paths must give the same tables (up to float32
rounding: the network's thread counts differ). Interleaving keeps a noisy
machine's drift out of the comparison (see ``benchmarks/README.md``).
"""

from __future__ import annotations

import argparse
import threading
import time

import numpy as np
import torch

from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.runtime.threads import single_blas_thread
from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.codec.prepare import _apply_mask
from brdfcodec.layers.detail import decode_detail
from brdfcodec.representation import clamp_mapped, table_from_mapped


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=200)
    parser.add_argument("--bytes", type=int, default=16384)
    parser.add_argument("--latent-dtype", choices=["float32", "float16"], default="float32")
    args = parser.parse_args()
    encoder = BrdfEncoder(effort=0, bytes=args.bytes, latent_dtype=args.latent_dtype, project_base="never")
    record = encoder.encode(ANALYTIC_PRESETS["gold"].to_merl(), name="gold")
    decoder = BrdfDecoder()
    decoder.decode(record)  # loads the shared basis
    basis, base = decoder.shared_basis, record.base()

    def layers_beside_the_network() -> np.ndarray:
        layers: list[np.ndarray] = []

        def residual() -> None:
            summed = basis.residual(record.basis.coefficients(), record.basis.first)
            if record.detail is not None:
                summed += decode_detail(record.detail).reshape(summed.shape)
            layers.append(summed)

        threads = torch.get_num_threads()
        with single_blas_thread():
            beside = threading.Thread(target=residual)
            torch.set_num_threads(max(1, threads - 1))
            beside.start()
            try:
                mapped = decoder.decode_mapped(record.mu)
            finally:
                beside.join()
                torch.set_num_threads(threads)
            mapped += layers[0]
            return _apply_mask(table_from_mapped(clamp_mapped(mapped, out=mapped)), None, "unmeasured")

    current = "decoder (layers after the network)"
    paths = {"base only": lambda: decoder.decode(base), "layers beside the network": layers_beside_the_network,
             current: lambda: decoder.decode(record)}
    if not np.allclose(paths["layers beside the network"](), paths[current](), rtol=1e-5, atol=1e-6):
        raise SystemExit("the two layered paths disagree")
    times: dict[str, list[float]] = {label: [] for label in paths}
    for _ in range(args.rounds):
        for label, decode in paths.items():
            if label != "base only":
                decoder.decode(base)  # as in the benchmark: each layered decode follows a base-only one
            start = time.perf_counter()
            decode()
            times[label].append(time.perf_counter() - start)
    base_times = np.array(times["base only"])
    for label, values in times.items():
        ratio = "" if label == "base only" else f"   {np.median(np.array(values) / base_times):.2f}× base-only"
        print(f"{label:>40}: {np.median(values) * 1e3:6.2f} ms{ratio}")


if __name__ == "__main__":
    main()
