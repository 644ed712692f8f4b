"""Encoding with effort and rate control: what :class:`~brdfcodec.codec.BrdfEncoder` runs per batch."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from brdfcodec.bvae_format import LatentRecord
from brdfcodec.layers.rate import Metric, encode_layers
from brdfcodec.layers.refine import EFFORT_STEPS, refine_latent

if TYPE_CHECKING:
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.merl import MerlBRDF

__all__ = ["EncodeOptions", "layer_records"]


@dataclass(frozen=True)
class EncodeOptions:
    """How hard to encode and what to aim for.

    Attributes
    ----------
    effort : int
        0 to 3: Adam steps of latent refinement (0: the encoder's μ).
    bytes_budget : int, optional
        Largest record payload per material (base + detail layer).
    max_relae : float, optional
        Largest RelAE of the decoded table against its source.
    metric : {"mapped", "linear"}
        RelAE used by ``max_relae``.
    detail_step : float, optional
        A fixed detail quantisation step (mapped units) instead of a target.
    latent_itemsize : int
        Bytes per stored latent value (4 for float32 files, 2 for float16).
    """

    effort: int = 1
    bytes_budget: int | None = None
    max_relae: float | None = None
    metric: Metric = "mapped"
    detail_step: float | None = None
    latent_itemsize: int = 4

    def __post_init__(self) -> None:
        if self.effort not in EFFORT_STEPS:
            raise ValueError(f"effort must be one of {sorted(EFFORT_STEPS)}, got {self.effort!r}")
        targets = [x for x in (self.bytes_budget, self.max_relae, self.detail_step) if x is not None]
        if len(targets) > 1:
            raise ValueError("give at most one of bytes (size budget), max_relae (error target) or detail_step")
        if self.bytes_budget is not None and self.bytes_budget < 1:
            raise ValueError(f"the size budget must be a positive number of bytes, got {self.bytes_budget}")
        if self.max_relae is not None and not (np.isfinite(self.max_relae) and self.max_relae > 0):
            raise ValueError(f"max_relae must be a positive number, got {self.max_relae}")
        if self.metric not in ("mapped", "linear"):
            raise ValueError(f"metric must be 'mapped' or 'linear', got {self.metric!r}")

    @property
    def layered(self) -> bool:
        """Whether records get a detail layer (a target or a step is set)."""
        return any(x is not None for x in (self.bytes_budget, self.max_relae, self.detail_step))


def layer_records(
    records: Sequence[LatentRecord],
    decoder: BrdfDecoder,
    inputs: np.ndarray,
    masks: np.ndarray,
    sources: Sequence[MerlBRDF | None],
    options: EncodeOptions,
) -> list[LatentRecord]:
    """Refine the base codes of records, then add detail layers as the options ask.

    A refined record's ``mu`` is the refined code and its ``sigma`` the
    encoder's; ``meta["effort"]`` says how it was made and, with a target,
    ``meta["rate"]`` what rate control chose.
    """
    mu = np.stack([r.mu for r in records])
    codes = refine_latent(decoder.network, mu, inputs, masks, options.effort)
    out: list[LatentRecord] = []
    base_mapped = decoder.decode_mapped(codes) if options.layered else None
    for i, record in enumerate(records):
        meta: dict[str, Any] = {**record.meta, "effort": options.effort}
        base = LatentRecord(record.name, codes[i], record.sigma, meta)
        if base_mapped is None:
            out.append(base)
            continue
        source = sources[i]
        if options.max_relae is not None and source is None:
            raise ValueError(f"{record.name}: --max-relae needs the source table to measure the error")
        result = encode_layers(
            base, base_mapped[i], inputs[i], masks[i],
            values=None if source is None else source.values,
            mask=None if source is None else source.mask,
            bytes_budget=options.bytes_budget, max_relae=options.max_relae, metric=options.metric,
            step=options.detail_step, latent_itemsize=options.latent_itemsize,
        )
        chosen = result.record
        rate = {"payload_bytes": result.payload_bytes, "candidates_tried": len(result.tried)}
        if options.bytes_budget is not None:
            rate["bytes_budget"] = options.bytes_budget
        if options.max_relae is not None:
            rate["max_relae"] = options.max_relae
            rate["metric"] = options.metric
        new_meta = {**chosen.meta, "rate": rate}
        if type(chosen) is LatentRecord:
            out.append(LatentRecord(chosen.name, chosen.mu, chosen.sigma, new_meta))
        else:
            out.append(type(chosen)(chosen.name, chosen.mu, chosen.sigma, new_meta, detail=chosen.detail))  # type: ignore[call-arg,attr-defined]
    return out
