"""The decoder's raw output split into its two paths: the linear basis and the convolutional correction.

A diagnostic for implausible decodes (``bvae model plausibility``, the model card): which path pushes an
output past the mapped domain.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["decompose_output"]


def decompose_output(decoder: Any, codes: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """The decoder's raw output before the clamp, split into its linear-basis path and convolutional correction.

    For a ``linear_basis`` model (:class:`brdfcodec.models.network.Decoder`)
    the unclamped output is ``linear + correction``; the decoded mapped value
    is its clamp to ``[0, MAPPED_MAX]``. Used to find which path causes an
    implausible decode.

    Parameters
    ----------
    decoder : BrdfDecoder
    codes : array_like, shape (B, latent_dim)

    Returns
    -------
    linear, correction : ndarray of float32, shape (B, 63, 90, 90)
        ``linear`` is 0 below the horizon (and everywhere for a model without a linear path).

    Raises
    ------
    ValueError
        The network is not a :class:`~brdfcodec.models.network.Decoder`.
    """
    import torch

    network = decoder.network
    if not hasattr(network, "logits") or not hasattr(network, "unbounded"):
        raise ValueError("decompose_output needs a brdfcodec Decoder network (with logits and unbounded)")
    z = torch.from_numpy(np.array(codes, dtype=np.float32)).reshape(-1, decoder.latent_dim)
    was_training = network.training
    network.eval()
    try:
        with torch.inference_mode():
            z = z.to(decoder.device, decoder.dtype)
            correction = network.logits(z).float()
            if network.config.linear_basis:
                linear = network.unbounded(z).float() - correction
            else:  # sigmoid output: no additive split; report it all as the correction
                correction = network.unbounded(z).float()
                linear = torch.zeros_like(correction)
    finally:
        network.train(was_training)
    return linear.cpu().numpy(), correction.cpu().numpy()
