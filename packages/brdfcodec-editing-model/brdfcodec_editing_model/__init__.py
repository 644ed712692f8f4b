"""The opt-in editing model of brdfcodec, ``bvae-nbrdf-proxy-edit-v1`` (issue 50).

The brdfcodec wheel ships one model, the codec's default (issue 52). This package holds a second one, made for
editing rather than for the smallest files: a 16-dimensional latent whose dimensions 1–8 were tied in training to
named factors of analytic materials (albedo, hue, specular, roughness, grazing, sheen, metallic, saturation); its
card measures what each slider moves. brdfcodec finds its folder (``models/editing``, ``spec/model.md`` §3) through
the entry point group ``brdfcodec.models``, which names :func:`models_folder`; ``--model editing`` picks it.
Nothing here is imported otherwise.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["models_folder"]


def models_folder() -> Path:
    """The folder holding this package's model folder (``editing``, with its ``model.json``)."""
    return Path(str(resources.files(__name__).joinpath("models")))
