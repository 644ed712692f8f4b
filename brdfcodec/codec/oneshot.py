"""The one-shot functions: encode, decode, compress and decompress.

Part of :mod:`brdfcodec.codec`, which re-exports the public names.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import TABLE_SHAPE
from brdfcodec.format.bvae import (
    LatentDtype,
    Record,
    encode_bvae,
    without_provenance,
)
from brdfcodec.io.atomic import atomic_output, check_output_path
from brdfcodec.io.inputs import read_measured
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.representation import (
    network_input_from_table,
)

if TYPE_CHECKING:
    from brdfcodec.codec.encoding import LatentChoice

from brdfcodec.codec.decoder import BrdfDecoder
from brdfcodec.codec.encoder import BrdfEncoder, MaterialInput, measure
from brdfcodec.codec.library import MaterialLibrary
from brdfcodec.codec.library_budget import ALLOCATIONS, allocate_library
from brdfcodec.codec.prepare import MaskedEntries, ModelSpec, prepare_source

__all__ = ["compress", "decode", "decompress", "encode", "encode_records"]

#: How a size budget is spent: per record, or over the library (:data:`~brdfcodec.codec.library_budget.ALLOCATIONS`).
Allocation = Literal["record", "library"]


EncodeSource = MerlBRDF | MaterialInput | npt.NDArray[np.floating] | str | os.PathLike[str]


def _is_one_source(sources: object) -> bool:
    """Whether ``sources`` is one source (a table of shape (3, 90, 90, 180) included), not an iterable of them."""
    if isinstance(sources, np.ndarray):
        return sources.ndim == len(TABLE_SHAPE)
    return isinstance(sources, MerlBRDF | MaterialInput | str | os.PathLike)


def _as_brdf(source: object, index: int) -> MerlBRDF:
    """A source that is not a :class:`MaterialInput` as a table: read from its file, or taken as it is."""
    if isinstance(source, MerlBRDF):
        return source
    if isinstance(source, str | os.PathLike):
        return read_measured(source)
    if isinstance(source, np.ndarray):
        if source.shape != TABLE_SHAPE or not (np.issubdtype(source.dtype, np.floating)
                                                or np.issubdtype(source.dtype, np.integer)):
            raise ValueError(f"source {index}: a table must be real numbers of shape {TABLE_SHAPE} ([channel, θh, "
                             f"θd, φd], stored MERL units), got {source.dtype} {source.shape}")
        values = np.asarray(source, dtype=np.float64)
        if not np.isfinite(values).all():
            raise ValueError(f"source {index}: the table holds {int(np.count_nonzero(~np.isfinite(values)))} "
                             "entries that are not finite (NaN or infinite); MERL marks unmeasured entries with "
                             "negative values")
        return MerlBRDF(values)
    raise TypeError(f"source {index}: expected a MERL .binary or RGL .bsdf path, a MerlBRDF, a MaterialInput or a "
                    f"table of shape {TABLE_SHAPE}, got {type(source).__name__}")


def as_material_input(source: EncodeSource, index: int, name: str | None) -> MaterialInput:
    """A source as a network input with its table (named ``name``, else by the source, else ``material-INDEX``).

    Raises
    ------
    TypeError
        ``source`` is none of the kinds :data:`EncodeSource` names.
    ValueError
        A table of another shape, of values that are not real numbers, or with entries that are not finite.
    """
    if isinstance(source, MaterialInput):
        return source if name is None else MaterialInput(name, source.inputs, source.source, source.mask)
    brdf = prepare_source(_as_brdf(source, index))
    label = name or brdf.name or f"material-{index}"
    inputs, mask = network_input_from_table(brdf.values, brdf.mask)
    return MaterialInput(label, inputs, brdf, mask)


def encode_records(
    sources: Iterable[EncodeSource],
    *,
    names: Sequence[str] | None = None,
    encoder: BrdfEncoder | None = None,
    decoder: BrdfDecoder | None = None,
    measure_error: bool = True,
    batch_size: int = 8,
    on_batch: Callable[[list[Record]], None] | None = None,
) -> list[Record]:
    """Encode materials into records, ``batch_size`` at a time (sources are read as they are needed).

    Parameters
    ----------
    sources : iterable of MerlBRDF, MaterialInput, MERL or RGL file path, or table (as for :func:`encode`)
        Consumed lazily, so a generator that loads one table at a time keeps
        at most ``batch_size`` tables in memory.
    names : sequence of str, optional
        Record names; by default each source's name (file stem, ``MerlBRDF.name``).
    encoder : BrdfEncoder, optional
        The shipped default model's encoder when absent.
    decoder : BrdfDecoder, optional
        For measuring; loaded from the encoder's model when needed.
    measure_error : bool, default True
        Decode each record and store its RelAE against its source table in
        ``meta["relae"]`` (skipped for a :class:`MaterialInput` without table).
    batch_size : int, default 8
    on_batch : callable, optional
        Called with the records of each batch as it is done (progress).

    Returns
    -------
    list of LatentRecord
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be at least 1, got {batch_size}")
    encoder = encoder if encoder is not None else BrdfEncoder()
    if measure_error and decoder is None:
        decoder = encoder.decoder
    labels = iter(names) if names is not None else itertools.repeat(None)
    records: list[Record] = []
    numbered = enumerate(sources)
    while chunk := list(itertools.islice(numbered, batch_size)):
        items = [as_material_input(source, index, next(labels)) for index, source in chunk]
        sources_of = [item.source for item in items]
        batch: list[Record] = list(encoder.encode_arrays(
            [item.name for item in items],
            np.stack([item.inputs for item in items]),
            np.stack([item.input_mask() for item in items]),
            sources_of,
        ))
        if measure_error and decoder is not None:
            batch = [r if s is None else measure(r, decoder, s) for r, s in zip(batch, sources_of, strict=True)]
        records += batch
        if on_batch is not None:
            on_batch(batch)
    return records


def encode(
    sources: EncodeSource | Iterable[EncodeSource],
    *,
    names: Sequence[str] | None = None,
    model: ModelSpec = None,
    latent_dtype: LatentDtype = "float32",
    measure_error: bool = True,
    batch_size: int = 8,
    effort: int = 1,
    bytes: int | None = None,  # noqa: A002 - the CLI's --bytes
    max_relae: float | None = None,
    metric: Literal["mapped", "linear"] = "mapped",
    provenance: bool = False,
    latent: LatentChoice = "always",
    coded_mu_step: int | tuple[int, ...] | None = None,
    short_references: bool = True,
    allocate: Allocation = "record",
    groups: Sequence[str] | None = None,
) -> bytes:
    """Encode MERL tables into the bytes of one ``.bvae`` file (one material, or a library of many).

    The inverse of :func:`decode`: ``decode(encode([brdf]))[brdf.name]`` is the
    material as the model reconstructs it.

    Parameters
    ----------
    sources : MerlBRDF, MaterialInput, MERL or RGL file path, table, or an iterable of them
        A table is an array of shape (3, 90, 90, 180) in stored MERL units (``[channel, θh, θd, φd]``, negative
        entries unmeasured, every entry finite); an array of shape (N, 3, 90, 90, 180) is N of them.
    names : sequence of str, optional
        Material names (by default the sources' names).
    model : model folder, decoder SHA-256, or None for the default
    latent_dtype : {"float32", "float16"}
    measure_error : bool, default True
        Measure each record's RelAE against its source (``meta["relae"]``; stored with ``provenance``).
    batch_size : int, default 8
    effort, bytes, max_relae, metric
        Encode-time refinement and rate control, as for :class:`BrdfEncoder`.
    provenance : bool, default False
        Store each record's provenance in the file (``spec/bvae-format.md`` §5: source SHA-256 and kind,
        RelAE, encoder, effort, rate control). By default the file holds names and records only.
    latent : {"always", "auto"}, default "always"
        Whether rate control may write records without a latent, as for :class:`BrdfEncoder`.
    coded_mu_step : int or tuple of int, optional
        The grid exponents of rate control's coded-μ candidates (one integer: that grid alone; 0: none), as for
        :class:`BrdfEncoder` (by default 2^−3 and 2^−2 under ``bytes`` of at most 32, 2^−2's records of at most
        32 bytes beside 2^−3's up to 40, else 2^−3).
    short_references : bool, default True
        Name the decoder and the shared basis by the first 8 bytes of their SHA-256 (format 2.6,
        ``spec/bvae-format.md`` §3.1): 24 bytes less a file, 48 with basis layers, and write a record form that
        differs from an earlier one in a few numbers as those numbers (format 2.7, §3.2). ``False`` writes their
        full hashes and every form in full, for readers older than 2.6.
    allocate : {"record", "library"}, default "record"
        With ``bytes`` N: ``"record"`` makes each record the best it can be within N bytes of its own (the header
        on top); ``"library"`` keeps the whole file within N bytes per material besides the names, its header
        included, and gives each material the bytes where they lower the library's error most
        (:func:`~brdfcodec.codec.library_budget.allocate_library`: about 8 times the encode time).
    groups : sequence of str, optional
        With ``allocate="library"``: a label per material; each group's materials then stay within their own N
        bytes each (their records and their share of the header), as a benchmark that scores them apart counts.

    Returns
    -------
    bytes
        A complete ``.bvae`` file (``spec/bvae-format.md``).

    Examples
    --------
    >>> import brdfcodec as bc
    >>> from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
    >>> data = bc.encode([ANALYTIC_PRESETS["gold"].to_merl()], measure_error=False)
    >>> data[1:5], len(data)   # one material: a header naming the decoder, then the 32 bytes of μ
    (b'BVAE', 83)
    >>> bc.decode(data)["gold"].table(phi_d_bins=[0]).shape
    (3, 90, 90, 1)
    """
    items = [sources] if _is_one_source(sources) else sources
    if allocate not in ALLOCATIONS:
        raise ValueError(f"allocate must be one of {list(ALLOCATIONS)}, got {allocate!r}")
    if allocate == "library" and bytes is None:
        raise ValueError("allocate='library' spreads a size budget over the library: give bytes")
    if groups is not None and allocate != "library":
        raise ValueError("groups apply to allocate='library'")
    encoder = BrdfEncoder(
        model, effort=effort, bytes=bytes, max_relae=max_relae, metric=metric, latent_dtype=latent_dtype,
        latent=latent, coded_mu_step=coded_mu_step,
    )
    if allocate == "library":
        labels = iter(names) if names is not None else itertools.repeat(None)
        sources_list = list(items)  # the sources (paths or tables as given): their count centres the ladder
        if groups is not None and len(groups) != len(sources_list):
            raise ValueError(f"groups gives {len(groups)} labels for {len(sources_list)} materials")
        records = allocate_library((as_material_input(source, index, next(labels))
                                    for index, source in enumerate(sources_list)), encoder,
                                   count=len(sources_list), groups=groups,
                                   latent_dtype=latent_dtype, short_references=short_references,
                                   provenance=provenance, batch_size=batch_size,
                                   decoder=encoder.decoder if measure_error else None)
    else:
        records = encode_records(items, names=names, encoder=encoder, measure_error=measure_error,
                                 batch_size=batch_size)
    if encoder.reference is None:  # loaded from a model folder, so it has one
        raise RuntimeError("the encoder has no decoder reference")
    if not provenance:
        records = without_provenance(records)
    return encode_bvae(records, encoder.reference, latent_dtype=latent_dtype, short_references=short_references)


def decode(data: bytes, *, decoder: BrdfDecoder | None = None) -> MaterialLibrary:
    """The materials of a ``.bvae`` file's bytes: the inverse of :func:`encode`.

    Parameters
    ----------
    data : bytes
        A complete ``.bvae`` file.
    decoder : BrdfDecoder, optional
        Reuse a loaded decoder; by default the one the file names is found by its SHA-256.

    Returns
    -------
    MaterialLibrary
        Name → :class:`DecodedMaterial`; each decoded when first used.

    Raises
    ------
    BvaeFormatError, DecoderNotFoundError, DecoderMismatchError
    """
    return MaterialLibrary.from_bytes(data, decoder=decoder)


def compress(
    sources: EncodeSource | Iterable[EncodeSource],
    output: str | os.PathLike[str],
    *,
    names: Sequence[str] | None = None,
    model: ModelSpec = None,
    latent_dtype: LatentDtype = "float32",
    measure_error: bool = True,
    overwrite: bool = False,
    effort: int = 1,
    bytes: int | None = None,  # noqa: A002 - the CLI's --bytes
    max_relae: float | None = None,
    metric: Literal["mapped", "linear"] = "mapped",
    provenance: bool = False,
    latent: LatentChoice = "always",
    coded_mu_step: int | tuple[int, ...] | None = None,
    short_references: bool = True,
    allocate: Allocation = "record",
) -> int:
    """Write :func:`encode` of the sources to a ``.bvae`` file, atomically (options as for :func:`encode`).

    Returns
    -------
    int
        Bytes written.
    """
    check_output_path(output, overwrite=overwrite)  # before the work, not after
    data = encode(
        sources, names=names, model=model, latent_dtype=latent_dtype, measure_error=measure_error,
        effort=effort, bytes=bytes, max_relae=max_relae, metric=metric, provenance=provenance, latent=latent,
        coded_mu_step=coded_mu_step, short_references=short_references, allocate=allocate,
    )
    with atomic_output(output, overwrite=overwrite) as tmp:
        Path(tmp).write_bytes(data)
    return len(data)


def decompress(
    path: str | os.PathLike[str],
    material: str | None = None,
    *,
    phi_d_bins: Sequence[int] | None = None,
    masked: MaskedEntries = "unmeasured",
) -> npt.NDArray[np.float32]:
    """Decode one material of a ``.bvae`` file (the only one, or the one named).

    Returns
    -------
    ndarray of float32, shape (3, 90, 90, K)
        Stored MERL units; see :meth:`BrdfDecoder.decode`.
    """
    with MaterialLibrary(path) as library:
        if material is None:
            if len(library) != 1:
                raise ValueError(
                    f"{path}: holds {len(library)} materials; name one ({', '.join(library.names[:10])}"
                    f"{', …' if len(library) > 10 else ''})"
                )
            material = library.names[0]
        return library[material].table(phi_d_bins=phi_d_bins, masked=masked)
