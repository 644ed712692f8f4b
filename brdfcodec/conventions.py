"""Constants of the MERL table and of the β-VAE input, as fixed by ``spec/conventions.md``.

Everything here is normative: changing a value changes the meaning of files
and trained models, and requires a new version of the spec.
"""

from __future__ import annotations

from typing import Final

import numpy as np

__all__ = [
    "BIN_TOLERANCE",
    "CONVENTIONS_VERSION",
    "EPSILON",
    "HORIZON_COS_MIN",
    "KEPT_PHI_D_SLICES",
    "MAPPED_MAX",
    "MERL_COLOR_SCALE",
    "MERL_SHAPE",
    "N_CHANNELS",
    "N_KEPT_SLICES",
    "N_PHI_D",
    "N_THETA_D",
    "N_THETA_H",
    "NETWORK_INPUT_SHAPE",
    "TABLE_SHAPE",
    "UNMEASURED_VALUE",
]

#: Version of ``spec/conventions.md`` that this module implements.
CONVENTIONS_VERSION: Final = "1.3"

#: Number of θh bins (non-linear, see :func:`brdfcodec.representation.coords.theta_h_index`).
N_THETA_H: Final = 90
#: Number of θd bins (linear over [0, π/2)).
N_THETA_D: Final = 90
#: Number of φd bins (linear over [0, π), reciprocity folds [π, 2π) onto it).
N_PHI_D: Final = 180
#: Number of colour channels (R, G, B).
N_CHANNELS: Final = 3

#: Dimensions written in the header of a MERL ``.binary`` file, in file order.
MERL_SHAPE: Final = (N_THETA_H, N_THETA_D, N_PHI_D)
#: In-memory layout of a BRDF table: ``[channel, θh, θd, φd]``.
TABLE_SHAPE: Final = (N_CHANNELS, N_THETA_H, N_THETA_D, N_PHI_D)

#: Factor that turns a stored MERL value into linear RGB reflectance (1/sr).
#: The paper's text says 1.5/1500 for green; MERL's own reader uses 1.15/1500.
MERL_COLOR_SCALE: Final = np.array([1.0, 1.15, 1.66]) / 1500.0
MERL_COLOR_SCALE.setflags(write=False)

#: ε of the log mapping (paper, eq. 1).
EPSILON: Final = 0.01

#: Upper end of the mapped domain. Decoder outputs are clamped to
#: ``[0, MAPPED_MAX]`` before the inverse mapping, which keeps every decoded
#: value finite in float32: 5.0 maps back to 0.01·(101⁵ − 1) ≈ 1.05e8 /sr
#: (physical) in every channel, above the sharpest analytic mirror we
#: generate (chrome, α = 0.01: 2.2e6 /sr) and far above measured data.
MAPPED_MAX: Final = 5.0

#: Bound on each latent coordinate at the decoder's input (``spec/bvae-format.md`` §6 step 2): a code is
#: clipped to ``[−LATENT_LIMIT, LATENT_LIMIT]`` before the network. Encoders give codes within a few units
#: (the prior is N(0, 1)), edits within tens; codes far beyond saturate the output, and in float32 the network's
#: arithmetic on them depends on the device, so the clip gives them one decode on every device (CPU against CUDA
#: by code magnitude: ``benchmarks/device/extreme_latents.py``, rows in ``reports/device/``).
LATENT_LIMIT: Final = 1e3

#: The φd slices kept as network input: every 9th slice from 0 to 171, plus
#: the last slice, 179, so that decoding interpolates and never extrapolates.
KEPT_PHI_D_SLICES: Final = tuple(range(0, N_PHI_D, 9)) + (N_PHI_D - 1,)
#: Number of kept φd slices (21).
N_KEPT_SLICES: Final = len(KEPT_PHI_D_SLICES)
#: Shape of one network input: ``21 · 3`` channels of 90×90 (θh rows, θd columns).
NETWORK_INPUT_SHAPE: Final = (N_CHANNELS * N_KEPT_SLICES, N_THETA_H, N_THETA_D)

#: An entry is above the horizon when the cosines of both its incoming and
#: outgoing directions (at the bin's representative angles) exceed this.
HORIZON_COS_MIN: Final = 1e-9

#: Bin coordinates within this distance below an integer count as that
#: integer, so that a bin's own representative angle always lands in it
#: despite floating-point rounding (see ``spec/conventions.md``).
BIN_TOLERANCE: Final = 1e-9

#: Value written to a MERL file for an entry that holds no measurement.
#: Any negative stored value means "unmeasured" when reading.
UNMEASURED_VALUE: Final = -1.0
