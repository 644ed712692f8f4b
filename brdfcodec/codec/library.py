"""A ``.bvae`` file opened as a mapping of materials, decoded lazily.

Part of :mod:`brdfcodec.codec`, which re-exports the public names.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.errors import (
    DecoderNotFoundError,
)
from brdfcodec.format.bvae import (
    BvaeHeader,
    BvaeReader,
    Record,
    parse_bvae,
)
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.representation import (
    reflectance_from_mapped,
    table_from_mapped,
    validate_phi_d_bins,
)
from brdfcodec.representation.energy import energy_bound_scale_mapped
from brdfcodec.representation.mask import horizon_mask

if TYPE_CHECKING:
    pass

from brdfcodec.codec.decoder import BrdfDecoder, is_edited
from brdfcodec.codec.prepare import MaskedEntries, _apply_mask

__all__ = ["DecodedMaterial", "MaterialLibrary"]


class DecodedMaterial:
    """One material of a library, decoded on first use and cached.

    Parameters
    ----------
    record : LatentRecord or GraftRecord
    decoder : BrdfDecoder
        Must be the decoder the record was made for (the library checks it).
    """

    def __init__(self, record: Record, decoder: BrdfDecoder) -> None:
        self.record = record
        self.decoder = decoder

    @property
    def name(self) -> str:
        """Material name."""
        return self.record.name

    @functools.cached_property
    def mapped(self) -> npt.NDArray[np.float32]:
        """Decoder output, (63, 90, 90) mapped slices in [0, MAPPED_MAX] (computed once), before the energy
        bound (:attr:`energy_scale`), which applies to the interpolated table (``spec/bvae-format.md`` §6)."""
        return self.decoder.mapped_record(self.record, energy_bound=False)

    @functools.cached_property
    def energy_scale(self) -> float:
        """The factor on this material's table: the energy bound ``min(1, 1 / max a)`` of an edited record
        (``spec/bvae-format.md`` §6 step 5), 1 for any other."""
        return energy_bound_scale_mapped(self.mapped) if is_edited(self.record) else 1.0

    def table(
        self, *, phi_d_bins: Sequence[int] | None = None, masked: MaskedEntries = "unmeasured"
    ) -> npt.NDArray[np.float32]:
        """Stored-unit table, all or chosen φd bins (see :meth:`BrdfDecoder.decode`).

        Chosen bins of a material not yet decoded are decoded alone (only the
        kept slices they need); the full decode is cached once made.
        """
        if phi_d_bins is None:
            return _apply_mask(table_from_mapped(self.mapped, scale=self.energy_scale), None, masked)
        if "mapped" not in self.__dict__:
            return self.decoder.decode(self.record, phi_d_bins=phi_d_bins, masked=masked)
        bins = validate_phi_d_bins(phi_d_bins)
        return _apply_mask(table_from_mapped(self.mapped, phi_d_bins=bins, scale=self.energy_scale), bins, masked)

    @functools.cached_property
    def _reflectance(self) -> npt.NDArray[np.float32]:
        table = _apply_mask(reflectance_from_mapped(self.mapped, scale=self.energy_scale), None, "zero")  # no trip through stored units
        table.setflags(write=False)
        return table

    def reflectance(self) -> npt.NDArray[np.float32]:
        """Reflectance in 1/sr, linear RGB, shape (3, 90, 90, 180); 0 below the horizon (cached, read-only)."""
        return self._reflectance

    #: Former name of :meth:`reflectance`.
    physical = reflectance

    def eval(
        self, wi: npt.ArrayLike, wo: npt.ArrayLike, *, mode: Literal["nearest", "trilinear"] = "nearest"
    ) -> npt.NDArray[np.float64]:
        """Reflectance (1/sr, linear RGB) at direction pairs, shape (..., 3)

        See :func:`brdfcodec.representation.lookup.lookup`.
        """
        from brdfcodec.representation.lookup import lookup

        mask = np.broadcast_to(horizon_mask(), (3, *horizon_mask().shape))
        return lookup(self._reflectance, wi, wo, mode=mode, mask=mask)

    def to_merl(self, *, masked: MaskedEntries = "unmeasured") -> MerlBRDF:
        """The decoded table as a :class:`~brdfcodec.io.merl.MerlBRDF` (float64, for writing or metrics)."""
        return MerlBRDF(self.table(masked=masked).astype(np.float64), name=self.name)


class MaterialLibrary(Mapping[str, DecodedMaterial]):
    """A ``.bvae`` file (or its bytes) opened for decoding materials on demand: name → :class:`DecodedMaterial`.

    Opening reads the header only and checks that ``decoder`` (or the model
    found by the file's decoder hash) is the one the file needs. Indexing by
    name reads that record and returns a lazily decoded, cached
    :class:`DecodedMaterial`. This is the one library class: :func:`decode`
    returns it for bytes, ``MaterialLibrary(path)`` opens a file.

    Parameters
    ----------
    path : str or os.PathLike
    decoder : BrdfDecoder, optional
        Reuse a loaded decoder; it must match the file.

    Raises
    ------
    DecoderNotFoundError, DecoderMismatchError, BvaeFormatError

    Examples
    --------
    >>> import brdfcodec as bc
    >>> from brdfcodec.examples import example_library
    >>> with bc.MaterialLibrary(example_library()) as library:
    ...     print(len(library), library.names[:2], library["gold-metallic-paint"].table(phi_d_bins=[90]).shape)
    90 ['alumina-oxide', 'aluminium'] (3, 90, 90, 1)
    """

    def __init__(self, path: str | os.PathLike[str], *, decoder: BrdfDecoder | None = None) -> None:
        self.path: Path | None = Path(path)
        reader = BvaeReader(path)
        try:
            self._open(reader.header, reader.read, reader.close, decoder, path)
        except BaseException:
            reader.close()
            raise

    def _open(
        self,
        header: BvaeHeader,
        read: Callable[[str], Record],
        close: Callable[[], None],
        decoder: BrdfDecoder | None,
        where: str | os.PathLike[str],
    ) -> None:
        self.header = header
        self._read = read
        self._close = close
        try:
            self.decoder = decoder if decoder is not None else BrdfDecoder.for_header(header)
        except DecoderNotFoundError as error:  # say which file needs the missing decoder
            raise type(error)(f"{os.fspath(where)}: {error}") from None
        self.decoder.check(header, where)
        self._materials: dict[str, DecodedMaterial] = {}

    @classmethod
    def from_bytes(cls, data: bytes, *, decoder: BrdfDecoder | None = None) -> MaterialLibrary:
        """A library from the bytes of a ``.bvae`` file (parsed and checked at once, records decoded lazily)."""
        parsed = parse_bvae(bytes(data))
        records = {record.name: record for record in parsed.records}
        library = cls.__new__(cls)
        library.path = None
        library._open(parsed.header, records.__getitem__, lambda: None, decoder, "<bytes>")
        return library

    def __enter__(self) -> MaterialLibrary:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the file (decoded materials stay usable)."""
        self._close()

    @property
    def names(self) -> list[str]:
        """Material names in file order."""
        return self.header.names

    def __len__(self) -> int:
        return len(self.header.entries)

    def __iter__(self) -> Iterator[str]:
        return iter(self.header.names)

    def __contains__(self, name: object) -> bool:
        return name in self.header.names

    def __getitem__(self, name: str) -> DecodedMaterial:
        if name not in self._materials:
            self._materials[name] = DecodedMaterial(self._read(name), self.decoder)
        return self._materials[name]

    def forget(self, name: str | None = None) -> None:
        """Drop a decoded material (or all) from the cache; it is decoded again if used again."""
        if name is None:
            self._materials.clear()
        else:
            self._materials.pop(name, None)

    def record(self, name: str) -> Record:
        """The stored record of a material (no decoding)."""
        return self[name].record

    @property
    def decoded_count(self) -> int:
        """How many materials have been decoded so far."""
        return sum("mapped" in m.__dict__ for m in self._materials.values())


