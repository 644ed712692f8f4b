"""The basis layer: a few quantised coefficients on a basis shared by every material (``spec/bvae-format.md`` §4.4).

A model may ship a *shared basis* (``basis.safetensors`` beside its weights,
``spec/model.md`` §5): K orthonormal vectors over the entries of the mapped
kept slices that lie above the horizon, fitted by :func:`fit_shared_basis`
when the model is exported — the principal components of the training
materials' mapped kept slices. A record's basis layer holds k integer
coefficients ``q`` of the vectors ``first … first + k − 1`` (≤ K) and one
float16 step ``s``; decoding adds ``s · Σᵢ qᵢ · b_(first+i)`` to the
decoder's output for μ (before the detail layer, the clamp and the
interpolation).

This is the low-rate enhancement: between the 8-D latent (32 B as float16)
and the per-material detail layer (hundreds of bytes and up), each extra
byte buys one more coefficient. Which basis was chosen by measurement on
materials the model was not trained on, not guessed (documentation: Layers
and rate control): the principal components of the training *data* beat
those of the training *residuals* (what the decoder leaves on the materials
it was trained on, which it fits far better than new ones) at all but the
smallest coefficient counts. Fitting μ and the coefficients together on the
L1 error (the encoder's way) lowers the data basis' error below PCA of the
same size with least squares.

This module does not import torch (the encoder's joint fit is in
:mod:`brdfcodec.codec.refine`).

The parts: :mod:`~brdfcodec.layers.quantise`, :mod:`~brdfcodec.layers.shared_basis`,
:mod:`~brdfcodec.layers.basis_layer`, :mod:`~brdfcodec.layers.basis_storage`; packed and entropy-coded
coefficients (formats 2.3, 2.4): :mod:`~brdfcodec.layers.packed`, :mod:`~brdfcodec.layers.coded_basis`.
This module gathers their names.
"""

# ruff: noqa: F401 - the names of the parts, gathered
from brdfcodec.errors import BasisError, BasisMismatchError
from brdfcodec.layers.basis_layer import (
    BasisLayer,
    basis_layer_from_bytes,
    check_basis_layers,
    check_records_without_latent,
    coded_coefficients,
    packed_coefficients,
    quantise_coefficients,
)
from brdfcodec.layers.basis_storage import (
    _load_cached,
    _load_checked,
    _validate,
    load_shared_basis,
    model_basis_lookup,
    write_factorised_basis,
    write_shared_basis,
)
from brdfcodec.layers.quantise import (
    _COLUMN_BLOCK,
    _ENTRIES_PER_CHANNEL,
    _N_ENTRIES,
    BASIS_FILE,
    FIXED_MU_LIMIT,
    FIXED_MU_STEP,
    MAX_BASIS_COUNT,
    STEP_BYTES,
    dequantise_int8,
    fits_fixed_mu_grid,
    int8_from_step_bytes,
    int8_on_fixed_grid,
    int8_step_bytes,
    int8_with_step,
)
from brdfcodec.layers.shared_basis import (
    _FACTORISED_TENSORS,
    FactorisedBasis,
    SharedBasis,
    _factorised,
    basis_offset,
    extend_factorised_basis,
    fit_factorised_basis,
    fit_shared_basis,
    linear_path_entries,
    quantise_factors,
    shared_basis_rank,
    with_colour_permutations,
)

__all__ = [
    "BASIS_FILE",
    "FIXED_MU_LIMIT",
    "BasisError",
    "FIXED_MU_STEP",
    "MAX_BASIS_COUNT",
    "BasisLayer",
    "FactorisedBasis",
    "SharedBasis",
    "basis_layer_from_bytes",
    "basis_offset",
    "check_basis_layers",
    "check_records_without_latent",
    "dequantise_int8",
    "extend_factorised_basis",
    "fit_factorised_basis",
    "fit_shared_basis",
    "fits_fixed_mu_grid",
    "int8_from_step_bytes",
    "int8_on_fixed_grid",
    "int8_step_bytes",
    "int8_with_step",
    "load_shared_basis",
    "model_basis_lookup",
    "packed_coefficients",
    "quantise_coefficients",
    "quantise_factors",
    "shared_basis_rank",
    "with_colour_permutations",
    "write_factorised_basis",
    "write_shared_basis",
]
