"""Interleaved A/B of a layered decode: layers after the network, one after the other, against the decoder's path.

Usage::

    python benchmarks/decode_layers_ab.py [--rounds 200] [--bytes 16384] [--latent-dtype float32]

The analytic ``gold`` material, encoded with ``--bytes 16384`` (75 basis
coefficients and a detail layer; ``--bytes 64 --latent-dtype float16`` is
the ``decode-layered-64B`` benchmark's record, basis coefficients only), is decoded base-only, with the layers
summed after the network on one thread, and the decoder's way (the layers on
a thread of their own beside the network, which runs on one torch thread
fewer), in turn, ``rounds`` times. Printed: the median time of each, in ms,
and the median over rounds of each layered time divided by the same round's
base-only time. The two layered paths must give the same tables (up to
float32 rounding: the network's thread counts differ). Interleaving keeps a
noisy machine's drift out of the comparison (see ``benchmarks/README.md``).
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
    parser.add_argument("--bytes", type=int, default=16384)
    parser.add_argument("--latent-dtype", choices=["float32", "float16"], default="float32")
    args = parser.parse_args()
    encoder = BrdfEncoder(effort=0, bytes=args.bytes, latent_dtype=args.latent_dtype)
    record = encoder.encode(ANALYTIC_PRESETS["gold"].to_merl(), name="gold")
    decoder = BrdfDecoder()
    decoder.decode(record)  # loads the shared basis
    basis, base = decoder.shared_basis, record.base()

    def layers_after_the_network() -> np.ndarray:
        with single_blas_thread():
            mapped = decoder.decode_mapped(record.mu)
            mapped += basis.residual(record.basis.coefficients(), record.basis.first)
            if record.detail is not None:
                mapped += decode_detail(record.detail).reshape(mapped.shape)
            return _apply_mask(table_from_mapped(clamp_mapped(mapped, out=mapped)), None, "unmeasured")

    current = "decoder (layers beside the network)"
    paths = {"base only": lambda: decoder.decode(base), "layers after the network": layers_after_the_network,
             current: lambda: decoder.decode(record)}
    if not np.allclose(paths["layers after the network"](), paths[current](), rtol=1e-5, atol=1e-6):
        raise SystemExit("the two layered paths disagree")
    times: dict[str, list[float]] = {label: [] for label in paths}
    for _ in range(args.rounds):
        for label, decode in paths.items():
            start = time.perf_counter()
            decode()
            times[label].append(time.perf_counter() - start)
    base_times = np.array(times["base only"])
    for label, values in times.items():
        ratio = "" if label == "base only" else f"   {np.median(np.array(values) / base_times):.2f}× base-only"
        print(f"{label:>40}: {np.median(values) * 1e3:6.2f} ms{ratio}")


if __name__ == "__main__":
    main()
