"""Reading training checkpoints (``best.pt``, ``checkpoint.pt``) without running code from them.

A checkpoint is a PyTorch file: a pickle. Unpickled in full (``weights_only=False``) it can call any function
(``os.system``…), so a run folder from elsewhere could run code when exported or resumed. Checkpoints are read
with ``weights_only=True``: PyTorch's restricted unpickler, which rebuilds tensors and plain values (dicts,
lists, tuples, numbers, strings) and refuses anything else unread.
"""

from __future__ import annotations

import os
import pickle
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from brdfcodec.errors import CheckpointError

__all__ = ["load_checkpoint"]


def load_checkpoint(
    path: str | os.PathLike[str], *, required: Mapping[str, type | tuple[type, ...]], map_location: Any = "cpu"
) -> dict[str, Any]:
    """A checkpoint's contents, read with PyTorch's restricted unpickler (no code runs), and checked.

    Parameters
    ----------
    path : str or os.PathLike
        The checkpoint file.
    required : mapping of str to type
        Keys the checkpoint must hold and the type of each value.
    map_location : str, torch.device or callable
        Where tensors go (:func:`torch.load`).

    Returns
    -------
    dict
        The checkpoint.

    Raises
    ------
    CheckpointError
        The file is not a PyTorch file, holds anything but tensors and plain values (a pickle that would
        run code is refused before any of it runs), is not a mapping, or lacks a required key or type.
    FileNotFoundError, IsADirectoryError, PermissionError
        As :func:`open` does.
    """
    file = Path(path)
    try:
        state = torch.load(file, map_location=map_location, weights_only=True)
    except OSError:
        raise
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError, AttributeError,
            ImportError, IndexError, KeyError) as error:
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise CheckpointError(
            file, f"not a checkpoint of tensors and plain values, refused unread: a file that needs more to load "
            f"(a pickle that would run code) is never loaded ({first[:200]})") from None
    if not isinstance(state, dict):
        raise CheckpointError(file, f"a checkpoint is a mapping, got {type(state).__name__}")
    for key, kind in required.items():
        if key not in state:
            raise CheckpointError(file, f"lacks {key!r}: not a checkpoint written by `bvae train`")
        if not isinstance(state[key], kind) or isinstance(state[key], bool) and bool not in _types(kind):
            raise CheckpointError(file, f"{key!r} is a {type(state[key]).__name__}, not what `bvae train` writes")
    return state


def _types(kind: type | tuple[type, ...]) -> tuple[type, ...]:
    return kind if isinstance(kind, tuple) else (kind,)
