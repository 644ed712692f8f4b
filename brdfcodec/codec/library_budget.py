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
from brdfcodec.format.bvae import DecoderReference, LatentDtype, Record, encode_bvae, without_provenance

if TYPE_CHECKING:
    from brdfcodec.codec.decoder import BrdfDecoder
    from brdfcodec.codec.encoder import BrdfEncoder, MaterialInput
    from brdfcodec.codec.encoding import Rung

__all__ = ["ALLOCATIONS", "allocate_library", "choose_rungs", "header_estimate"]

#: How a size budget is spent (``bvae compress --allocate``): ``"record"``, the default, makes each record the best
#: it can be within N bytes of its own; ``"library"`` keeps the whole file within n·N bytes besides the names, its
#: header included, and gives each material the bytes where they lower the error most.
ALLOCATIONS = ("record", "library")
#: The header a library's file is expected to take, in bytes: its fixed fields with short references and a shared
#: basis (preamble 24, decoder 8, latent size and dtype 3, basis 8, form and record counts 2, payload CRC 4) and
#: about 4.5 bytes a layer form, a form for each material up to 9. It centres the ladder's rungs on the mean budget
#: less its share; the choice itself is fitted to the header as written.
HEADER_FIXED = 49
HEADER_PER_FORM = 4.5
HEADER_FORMS = 9
#: The fewest bytes a library's header takes (preamble, short decoder reference, latent size and dtype, one form, the
#: record count and the payload CRC): below it and the smallest records, no library fits.
HEADER_FLOOR = 40
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
    N less the header's expected share, :func:`header_estimate`), its latent refined once;
    then each gets the rung that :func:`~brdfcodec.codec.allocation.allocate_bytes` chooses for the records'
    total: n·N less the header, which is measured on the file the choice writes and the choice redone until the
    file fits. The error compared across materials is rate control's kept-slice error over the material's own
    kept slices. Encoding takes about as many times longer than ``--bytes N`` alone as there are rungs (8).

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
    if batch_size < 1:
        raise ValueError(f"batch_size must be at least 1, got {batch_size}")
    if count is None:
        count = len(items) if isinstance(items, Sized) else None
    if count is not None and groups is not None and len(groups) != count:  # before the slow part
        raise ValueError(f"groups gives {len(groups)} labels for {count} materials")
    smallest = _smallest_record(encoder)
    floor = HEADER_FLOOR + (0 if short_references else FULL_REFERENCES_EXTRA)
    if count is not None and count * mean < floor + count * smallest:
        raise RateTargetError(f"{count} material{'s' if count != 1 else ''} cannot fit {mean} bytes each: the file's "
                              f"header takes at least {floor} bytes and each record at least {smallest}")
    centre = mean if count is None else mean - math.ceil(header_estimate(count, short_references) / max(count, 1))
    ladder = budget_ladder(max(centre, smallest), smallest=smallest)
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
    return choose_rungs(ladders, mean, encoder.reference, groups=groups, latent_dtype=latent_dtype,
                        short_references=short_references, provenance=provenance)


def choose_rungs(
    ladders: Sequence[Sequence[Rung]],
    mean: int,
    reference: DecoderReference,
    *,
    groups: Sequence[str] | None = None,
    latent_dtype: LatentDtype = "float32",
    short_references: bool = True,
    provenance: bool = False,
) -> list[Record]:
    """One rung's record per material such that the file they make holds within ``mean`` bytes per material
    besides the names (each group within its materials' share), with the lowest summed distortion found.

    The records' total is n·N less the header: first the header of the file of every material's smallest rung,
    then the header of the last choice's file, until a choice's file fits; where no larger choice fits, the
    smallest rungs are kept if their file does.

    Raises
    ------
    RateTargetError
        Not even the smallest rungs' file fits.
    ValueError
        ``groups`` does not give one label per material.
    """
    count = len(ladders)
    labels = list(groups) if groups is not None else [""] * count
    if len(labels) != count:
        raise ValueError(f"groups gives {len(labels)} labels for {count} materials")
    members = {label: [i for i in range(count) if labels[i] == label] for label in dict.fromkeys(labels)}
    name_bytes = sum(len(rungs[0].record.name.encode("utf-8")) for rungs in ladders)

    def measured(chosen: Sequence[int]) -> tuple[list[Record], bool, float]:
        """The chosen records, whether their file fits, and its header's bytes per material."""
        records = [ladders[i][chosen[i]].record for i in range(count)]
        record_bytes = [ladders[i][chosen[i]].record_bytes for i in range(count)]
        stored = records if provenance else without_provenance(records)
        size = len(encode_bvae(stored, reference, latent_dtype=latent_dtype, short_references=short_references))
        header = (size - name_bytes - sum(record_bytes)) / count
        fits = all(sum(record_bytes[i] for i in indices) + len(indices) * header <= len(indices) * mean
                   for indices in members.values())
        return records, fits, header

    smallest = [min(range(len(rungs)), key=lambda j, rungs=rungs: (rungs[j].record_bytes, rungs[j].distortion))
                for rungs in ladders]
    fallback, smallest_fits, header = measured(smallest)
    for _ in range(_ROUNDS):
        chosen = list(smallest)
        try:
            for indices in members.values():
                total = math.floor(len(indices) * (mean - header))
                picks = allocate_bytes([[(r.record_bytes, r.distortion) for r in ladders[i]] for i in indices],
                                       total)
                for i, pick in zip(indices, picks, strict=True):
                    chosen[i] = pick
        except RateTargetError:
            break  # no choice fits beside this header: the smallest rungs, if their file fits
        records, fits, now = measured(chosen)
        if fits:
            return records
        header = max(now, header + 1.0 / count)  # at least a byte less each round: the loop ends
    if smallest_fits:
        return fallback
    raise RateTargetError(f"{count} materials do not fit {mean} bytes each: the file of their smallest records "
                          f"takes {header:.1f} bytes a material of header beside them")


def header_estimate(count: int, short_references: bool = True) -> float:
    """The bytes a library of ``count`` materials is expected to spend on its header (:data:`HEADER_FIXED`).

    Parameters
    ----------
    count : int
        Materials in the library (at least one is assumed).
    short_references : bool, default True
        Whether the file names its decoder and basis by short references (else their whole SHA-256,
        :data:`FULL_REFERENCES_EXTRA` bytes more).

    Returns
    -------
    float
        Bytes: a first guess that rate control's header share starts from, before the file is written and measured.
    """
    fixed = HEADER_FIXED + (0 if short_references else FULL_REFERENCES_EXTRA)
    return fixed + HEADER_PER_FORM * min(max(count, 1), HEADER_FORMS)


def _smallest_record(encoder: BrdfEncoder) -> int:
    """The smallest record (bytes beyond a one-byte name) the encoder's model and options can write."""
    from brdfcodec.codec.rate import smallest_bytes_budget

    manifest = encoder.manifest
    if manifest is None:
        return 1
    options = encoder.options
    basis = options.basis and manifest.basis_sha256 is not None
    return smallest_bytes_budget(manifest.config.latent_dim, options.latent_itemsize, basis,
                                 without_latent=basis and options.latent == "auto" and bool(
                                     manifest.config.linear_basis), store_sigma=options.store_sigma)
