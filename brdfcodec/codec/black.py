"""Near-black sources: a record that decodes to exactly 0 (issue 49, R3-17).

A source whose every valid entry is below
:data:`~brdfcodec.representation.metrics.NEAR_BLACK_REFLECTANCE` (all zeros,
denormals, 1e-30 …) has no meaningful RelAE, and the network, trained on
materials that reflect light, decodes its code to a lit material. Such a
source gets the encoder's latent plus a detail layer of constant
−(MAPPED_MAX + 1): layers are added before the one clamp
(``spec/bvae-format.md`` §4.4), so every decoded entry is exactly 0 whatever
the base, and the absolute error is the source's own magnitude (< 1e-6 /sr).
"""

from __future__ import annotations

import functools

import numpy as np

from brdfcodec.conventions import MAPPED_MAX, NETWORK_INPUT_SHAPE
from brdfcodec.format.bvae import LatentDtype, LatentRecord
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.format.writer import record_size
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.layers.detail import DetailLayer, encode_detail
from brdfcodec.representation.metrics import near_black

__all__ = ["black_record", "is_near_black_source"]


def is_near_black_source(source: MerlBRDF | None) -> bool:
    """Whether ``source`` (a prepared table; None: unknown) is near black: its record should decode black."""
    return source is not None and near_black(source.values, source.mask)


@functools.cache
def _black_detail() -> DetailLayer:
    # The DCT's DC term alone: about 50 bytes, the same for every record.
    return encode_detail(np.full(NETWORK_INPUT_SHAPE, -(MAPPED_MAX + 1.0)), 1.0)


def black_record(record: LatentRecord, *, store_sigma: bool = False, bytes_budget: int | None = None,
                 latent_dtype: LatentDtype = "float32") -> LayeredRecord | None:
    """``record`` with a detail layer that takes every decoded entry to exactly 0.

    Parameters
    ----------
    record : LatentRecord
        The encoder's record of a near-black source (its μ is kept, so the
        record stays editable, and its meta).
    store_sigma : bool, default False
        Store the record's σ too.
    bytes_budget : int, optional
        Largest record (payload and descriptor, as ``--bytes`` counts): μ is
        stored on the compact fixed grid (one byte a dimension) where the
        full one does not fit.
    latent_dtype : {"float32", "float16"}, default "float32"
        The file's latent dtype.

    Returns
    -------
    LayeredRecord or None
        None when no black record fits ``bytes_budget`` (rate control then
        does what it can within the budget).
    """
    mu = np.asarray(record.mu, dtype=np.float32)
    sigma = np.asarray(record.sigma, dtype=np.float32) if store_sigma else np.ones_like(mu)
    for compact in (False, True):
        made = LayeredRecord(record.name, mu, sigma, dict(record.meta), detail=_black_detail(),
                             store_sigma=store_sigma, compact_mu=compact, fixed_mu_grid=compact)
        if bytes_budget is None or record_size(made, latent_dtype) <= bytes_budget:
            return made
    return None
