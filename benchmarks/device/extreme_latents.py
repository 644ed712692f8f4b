"""CPU against CUDA on latents far outside the prior: the network's output and the clamped mapped slices.

usage (a machine with a GPU; repository root): python benchmarks/device/extreme_latents.py

For each code (the extreme codes of tests/test_device_decode.py, then ±s in every coordinate for s = 1 … 1e8)
prints the count of NaN and infinite network outputs on each device and the largest |Δ| of the clamped mapped
slices (``decode_mapped``) between them. Its run on an H100 at 1da3432, before the decoder clipped its input
(spec/model.md 1.9), is reports/device/h100-1da3432/extreme-latents.log.
"""

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))

from test_device_decode import extreme_codes  # noqa: E402

from brdfcodec.codec import BrdfDecoder  # noqa: E402


def main() -> None:
    cpu, cuda = BrdfDecoder(), BrdfDecoder(device="cuda")
    codes = extreme_codes(cpu.latent_dim)
    for scale in [1.0, 10.0, 1e2, 1e3, 1e4, 1e5, 1e6, 1e8]:
        codes = np.concatenate([codes, np.full((1, cpu.latent_dim), scale, np.float32),
                                np.full((1, cpu.latent_dim), -scale, np.float32)])
    with torch.no_grad():
        for i, code in enumerate(codes):
            z = torch.from_numpy(code[None])
            on_cpu = cpu.network.eval()(z).float()
            on_cuda = cuda.network.eval()(z.cuda()).float().cpu()
            difference = np.abs(cpu.decode_mapped(code[None])[0] - cuda.decode_mapped(code[None])[0]).max()
            print(i, float(code[0]), "cpu nan/inf", int(on_cpu.isnan().sum()), int(on_cpu.isinf().sum()),
                  "cuda nan/inf", int(on_cuda.isnan().sum()), int(on_cuda.isinf().sum()),
                  "clamped max|d|", float(difference))


if __name__ == "__main__":
    main()
