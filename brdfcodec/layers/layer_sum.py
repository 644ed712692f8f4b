"""A layered record's residual: basis layer plus detail layer, as one array (full-table decodes).

The decoder computes it after the network, on the calling thread: the basis
sum on the shared basis' factors (bound by memory bandwidth: each factor its
coefficients use is read once), placed on the grid, then the detail layer's
residual added (its inverse DCT, bound by compute, only over the blocks that
hold nonzero coefficients: :func:`~brdfcodec.layers.detail.decode_detail`).
Run beside the network on a thread of its own, it would compete with
torch's threads for the cores and make a decode on a machine with few cores
slower, not faster (documentation: Development).

This module does not import torch.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import NETWORK_INPUT_SHAPE
from brdfcodec.layers.basis import BasisLayer, SharedBasis
from brdfcodec.layers.detail import DetailLayer, decode_detail

__all__ = ["layered_residual"]


def layered_residual(
    basis: SharedBasis | None, basis_layer: BasisLayer | None, detail: DetailLayer | None
) -> npt.NDArray[np.float32] | None:
    """The mapped residual that a record's layers add to its base decode, shape ``(63, 90, 90)``.

    Parameters
    ----------
    basis : SharedBasis or None
        The model's shared basis; required when ``basis_layer`` is given
        (the caller has checked that the layer was written for it).
    basis_layer : BasisLayer or None
        The record's basis layer.
    detail : DetailLayer or None
        The record's detail layer.

    Returns
    -------
    ndarray of float32, shape (63, 90, 90), or None
        Basis residual plus detail residual in mapped units; None when the
        record has neither layer.
    """
    if basis_layer is None:
        return None if detail is None else decode_detail(detail).reshape(NETWORK_INPUT_SHAPE)
    if basis is None:
        raise ValueError("a basis layer needs the shared basis it was written for")
    residual = basis.residual(basis_layer.coefficients(), basis_layer.first)
    if detail is not None:
        residual += decode_detail(detail).reshape(NETWORK_INPUT_SHAPE)
    return residual
