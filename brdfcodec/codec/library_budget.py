"""A library within a size: ``--bytes N --allocate library`` (the records of n materials and the file's header
within n·N bytes besides the names, bytes given where they lower the error most).

Part of :mod:`brdfcodec.codec`, which re-exports the public names.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Iterable, Sequence, Sized
from typing import TYPE_CHECKING

import numpy as np

from brdfcodec.codec.allocation import allocate_bytes, budget_ladder
from brdfcodec.codec.encoder import measure
from brdfcodec.errors import RateTargetError
from brdfcodec.format.bvae import LatentDtype, Record, encode_bvae, without_provenance

if TYPE_CHECKING:
    from brdfcodec.codec.decoder import BrdfDecoder
    from brdfcodec.codec.encoder import BrdfEncoder, MaterialInput
    from brdfcodec.codec.encoding import Rung

__all__ = ["ALLOCATIONS", "allocate_library"]

#: How a size budget is spent (``bvae compress --allocate``): ``"record"``, the default, makes each record the best
#: it can be within N bytes of its own; ``"library"`` keeps the whole file within n·N bytes besides the names, its
#: header included, and gives each material the bytes where they lower the error most.
ALLOCATIONS = ("record", "library")
#: The header a library's file is expected to take (bytes; short references, a few layer forms): where the ladder's
#: rungs are centred, the mean budget less its share (the choice itself is fitted to the header as written).
HEADER_ESTIMATE = 90
#: Bytes more with full references (the decoder's and the basis' whole SHA-256).
FULL_REFERENCES_EXTRA = 48
#: Most rounds of allocating, writing and measuring the header before giving up (the header's size depends on the
#: records chosen: their forms; it settles in one or two).
_ROUNDS = 8


def allocate_library(
    items: Iterable[MaterialInput],
    encoder: BrdfEncoder,
    *,
    count: int | None = None,
    groups: Sequence[str] | None = None,
    latent_dtype: LatentDtype = "float32",
    short_references: bool = True,
    provenance: bool = False,
    batch_size: int = 8,
    decoder: BrdfDecoder | None = None,
    on_batch: Callable[[int], None] | None = None,
) -> list[Record]:
    """The records of a library whose file holds within N bytes per material besides the names, N the
    encoder's size budget (``BrdfEncoder(bytes=N)``), with the lowest summed error library allocation finds.

    Each material is encoded at the rungs of :func:`~brdfcodec.codec.allocation.budget_ladder` (0.625 to 2 times
    N less the header's expected share, :data:`HEADER_ESTIMATE` over the materials), its latent refined once;
    then each gets the rung that :func:`~brdfcodec.codec.allocation.allocate_bytes` chooses for the records'
    total: n·N less the header, which is measured on the file the choice writes and the choice redone until the
    file fits. The error compared across materials is rate control's kept-slice error over the material's own
    kept slices. Encoding takes about as many times longer than ``--bytes N`` alone as there are rungs (7).

    Parameters
    ----------
    items : iterable of MaterialInput
        The materials (consumed ``batch_size`` at a time: at most that many tables are held at once).
    encoder : BrdfEncoder
        With a size budget ``bytes`` (its other options apply to every rung).
    count : int, optional
        How many materials ``items`` holds (its length where it has one): centres the ladder.
    groups : sequence of str, optional
        A label per material: each group's records and its materials' share of the header stay within its
        materials' N bytes each (as a benchmark that scores families apart counts), instead of the library as a
        whole.
    latent_dtype, short_references, provenance
        How the file will be written (:func:`~brdfcodec.format.bvae.encode_bvae`): they decide its header.
    batch_size : int, default 8
    decoder : BrdfDecoder, optional
        Measure every rung's record against its source table (``meta["relae"]``, as
        :func:`~brdfcodec.codec.encode_records` does; a decode per rung), where the material has one.
    on_batch : callable, optional
        Called with the number of materials each batch encoded (progress).

    Returns
    -------
    list of Record
        In the order of ``items``; ``meta["rate"]`` says which rung each came from.

    Raises
    ------
    RateTargetError
        The smallest records the materials can take and the header do not fit n·N bytes.
    ValueError
        The encoder has no size budget, or ``groups`` does not give one label per material.
    """
    mean = encoder.options.bytes_budget
    if mean is None:
        raise ValueError("library allocation needs a size budget: BrdfEncoder(bytes=N)")
    if encoder.reference is None:
        raise RuntimeError("the encoder has no decoder reference")
    if count is None:
        count = len(items) if isinstance(items, Sized) else None
    header_estimate = HEADER_ESTIMATE + (0 if short_references else FULL_REFERENCES_EXTRA)
    ladder = budget_ladder(max(1, mean - (0 if count is None else math.ceil(header_estimate / max(count, 1)))))
    ladders: list[list[Rung]] = []
    iterator = iter(items)
    while chunk := list(itertools.islice(iterator, batch_size)):
        made = encoder.encode_rungs([item.name for item in chunk], np.stack([item.inputs for item in chunk]),
                                    np.stack([item.input_mask() for item in chunk]), [item.source for item in chunk],
                                    ladder)
        if decoder is not None:
            made = [[dataclasses.replace(rung, record=measure(rung.record, decoder, item.source)) for rung in rungs]
                    if item.source is not None else rungs for item, rungs in zip(chunk, made, strict=True)]
        ladders += made
        if on_batch is not None:
            on_batch(len(chunk))
    count = len(ladders)
    labels = list(groups) if groups is not None else [""] * count
    if len(labels) != count:
        raise ValueError(f"groups gives {len(labels)} labels for {count} materials")
    members = {label: [i for i in range(count) if labels[i] == label] for label in dict.fromkeys(labels)}
    name_bytes = sum(len(rungs[0].record.name.encode("utf-8")) for rungs in ladders)
    reference = encoder.reference

    def written(records: list[Record]) -> int:
        stored = records if provenance else without_provenance(records)
        return len(encode_bvae(stored, reference, latent_dtype=latent_dtype, short_references=short_references))

    header = 0.0  # the file's bytes less the names and the records, per material; measured after each round
    for _ in range(_ROUNDS):
        chosen = [0] * count
        for indices in members.values():
            total = math.floor(len(indices) * (mean - header))
            picks = allocate_bytes([[(r.record_bytes, r.distortion) for r in ladders[i]] for i in indices], total)
            for i, pick in zip(indices, picks, strict=True):
                chosen[i] = pick
        records = [ladders[i][chosen[i]].record for i in range(count)]
        record_bytes = [ladders[i][chosen[i]].record_bytes for i in range(count)]
        size = written(records)
        measured = (size - name_bytes - sum(record_bytes)) / count
        if all(sum(record_bytes[i] for i in indices) + len(indices) * measured <= len(indices) * mean
               for indices in members.values()):
            return records
        header = max(measured, header + 1.0 / count)  # at least a byte less each round: the loop ends
    raise RateTargetError(f"{count} materials do not fit {mean} bytes each with the file's header "
                          f"({header:.1f} bytes per material) beside their smallest records")

