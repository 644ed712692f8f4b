"""Torch devices as tensors report them."""

from __future__ import annotations

import torch

__all__ = ["indexed_device"]


def indexed_device(device: str | torch.device) -> torch.device:
    """``device`` with the index torch gives its tensors there (``"cuda"`` is the current ``cuda:N``).

    A decoder made for ``"cuda"`` then compares equal to the device of the tensors it returns and of the tensors a
    caller makes on ``"cuda"`` (whose ``.device`` reads ``cuda:0``); devices without an index (``cpu``) and
    explicit indices are returned as they are.

    Parameters
    ----------
    device : str or torch.device
        Any device torch accepts.

    Returns
    -------
    torch.device
    """
    device = torch.device(device)
    if device.index is None and device.type not in ("cpu", "meta"):
        return torch.empty(0, device=device).device
    return device
