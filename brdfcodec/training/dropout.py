"""Dropout on the decoder's hidden fully connected units, for training only.

The mask is drawn with the batch's other random draws (``_global_batches``),
so a run stays reproducible, resumes exactly and gives every process its
slice of one global draw. The network itself is unchanged: the dropout is a
forward hook that exists only while training, so exported weights and their
format do not depend on it.
"""

from __future__ import annotations

import torch
from torch import nn

from brdfcodec.models.network import Decoder

__all__ = ["DecoderHiddenDropout", "hidden_width"]


def hidden_width(decoder: Decoder) -> int:
    """Width of the decoder's first hidden fully connected layer (the units dropout acts on).

    Raises
    ------
    ValueError
        When the decoder has no hidden fully connected layer.
    """
    widths = decoder.config.decoder_fc
    if not widths:
        raise ValueError("decoder dropout needs a hidden fully connected layer (decoder_fc is empty)")
    return widths[0]


class DecoderHiddenDropout:
    """Inverted dropout, with a given keep mask, on the decoder's first hidden fully connected activation.

    Parameters
    ----------
    decoder : Decoder
        The decoder to hook (its ``fc[1]``, the activation after ``z → decoder_fc[0]``).
    probability : float
        Probability in [0, 1) that a unit is dropped; kept units are scaled by ``1 / (1 − probability)``.
    """

    def __init__(self, decoder: Decoder, probability: float) -> None:
        if not 0 <= probability < 1:
            raise ValueError(f"dropout probability must be in [0, 1), got {probability}")
        self.width = hidden_width(decoder)
        self.scale = 1.0 / (1.0 - probability)
        self.keep: torch.Tensor | None = None
        activation: nn.Module = decoder.fc[1]
        self._handle = activation.register_forward_hook(self._apply)

    def set_keep(self, keep: torch.Tensor | None) -> None:
        """The keep mask ``(B, width)`` of the next training forward pass (bool), or None for none."""
        if keep is not None and keep.shape[-1] != self.width:
            raise ValueError(f"keep mask of width {keep.shape[-1]}, expected {self.width}")
        self.keep = keep

    def remove(self) -> None:
        """Take the hook off the decoder."""
        self._handle.remove()

    def _apply(self, module: nn.Module, inputs: tuple[torch.Tensor, ...], output: torch.Tensor) -> torch.Tensor:
        if not module.training or self.keep is None:
            return output
        return output * self.keep.to(device=output.device, dtype=output.dtype) * self.scale
