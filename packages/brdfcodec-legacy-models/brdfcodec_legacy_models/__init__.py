"""Earlier default models of brdfcodec, kept so that the ``.bvae`` files made with them decode.

The brdfcodec wheel ships one model (the current default). This package holds the ones it retired:
``bvae-nbrdf-proxy-small-v1`` and ``bvae-nbrdf-proxy-small-v2``, one model folder each
(``spec/model.md`` §3). brdfcodec finds them through the entry point group ``brdfcodec.models``, which
names :func:`models_folder`; nothing here is imported otherwise.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["models_folder"]


def models_folder() -> Path:
    """The folder holding this package's model folders (one per model, each with its ``model.json``)."""
    return Path(str(resources.files(__name__).joinpath("models")))
