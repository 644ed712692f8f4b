"""Typed errors of brdfcodec.

Every error raised for bad *data* derives from :class:`BrdfcodecError`; bad
*arguments* from a caller raise the built-in :class:`ValueError` or
:class:`TypeError`. File-system failures (missing file, a directory where a
file was expected) stay the built-in :class:`OSError` subclasses. Messages
name the file and say what is wrong and, where it helps, what to do.
"""

from __future__ import annotations

import os

__all__ = [
    "BasisError",
    "BasisMismatchError",
    "BrdfcodecError",
    "BvaeChecksumError",
    "BvaeFormatError",
    "CheckpointError",
    "DatasetError",
    "DecoderMismatchError",
    "DecoderNotFoundError",
    "FileFormatError",
    "LatentDimensionError",
    "MerlFormatError",
    "ModelChecksumError",
    "ModelFolderError",
    "ModelNotFoundError",
    "NoLatentError",
    "NonFiniteValueError",
    "OptionalDependencyError",
    "RateTargetError",
    "SourceFormatError",
    "UnmeasuredMaterialError",
    "UnsupportedVersionError",
]


class BrdfcodecError(Exception):
    """Base class of every data error raised by brdfcodec."""


class FileFormatError(BrdfcodecError, ValueError):
    """A file's content does not follow the format it is read as.

    Parameters
    ----------
    path : str or os.PathLike
        The offending file.
    problem : str
        What is wrong, as a sentence fragment.
    """

    def __init__(self, path: str | os.PathLike[str], problem: str) -> None:
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class MerlFormatError(FileFormatError):
    """A file is not a valid MERL ``.binary`` BRDF table."""


class NonFiniteValueError(MerlFormatError):
    """A MERL table holds NaN or infinite values (and masking was not asked for)."""


class SourceFormatError(FileFormatError):
    """A dataset source (an NBRDF fit archive, say) is malformed."""


class UnmeasuredMaterialError(MerlFormatError):
    """A MERL table has no measured entry above the horizon: there is nothing to compress."""


class DatasetError(FileFormatError):
    """An HDF5 dataset file is missing, malformed or of an unknown version."""


class BvaeFormatError(FileFormatError):
    """A file is not a valid ``.bvae`` file (bad magic, malformed header or records, trailing bytes)."""


class BvaeChecksumError(BvaeFormatError):
    """A CRC-32 stored in a ``.bvae`` file does not match the bytes it covers: the file is corrupt."""


class UnsupportedVersionError(BvaeFormatError):
    """A ``.bvae`` file needs a newer reader: unknown major version, flag or record kind."""


class LatentDimensionError(BvaeFormatError):
    """A ``.bvae`` file declares a latent size other than that of the decoder it names.

    Raised when the file is opened for decoding (``spec/bvae-format.md`` §6):
    the file and its decoder reference contradict each other.
    """


class DecoderNotFoundError(BrdfcodecError):
    """No installed or registered model has the decoder a ``.bvae`` file refers to."""


class DecoderMismatchError(BrdfcodecError):
    """A decoder other than the one a ``.bvae`` file refers to was offered for decoding it."""


class BasisMismatchError(DecoderMismatchError):
    """A record's basis layer names a shared basis that its decoder's model does not have."""


class BasisError(BrdfcodecError, ValueError):
    """A shared basis file that is malformed or not the one named, or a record that needs basis vectors its
    model's shared basis does not hold (``spec/bvae-format.md`` §4.5)."""


class NoLatentError(BrdfcodecError, ValueError):
    """A record stores no latent code (a basis-only layered record, ``spec/bvae-format.md`` §4.6), so it cannot be
    edited: edits move a latent code.

    Parameters
    ----------
    record : str
        The record's name.
    path : str or os.PathLike, optional
        The file that holds it, when known.
    """

    def __init__(self, record: str, path: str | os.PathLike[str] | None = None) -> None:
        self.record = record
        self.path = None if path is None else os.fspath(path)
        where = f"{self.path}: " if self.path else ""
        super().__init__(
            f"{where}record {record!r} has no latent code (a basis-only record, format 2.1), so it cannot be "
            "edited; re-encode the material with `bvae compress --latent always` for a record whose latent code "
            "can be edited"
        )


class ModelNotFoundError(DecoderNotFoundError):
    """No known model has the requested decoder (or the shipped default model is missing)."""


class ModelChecksumError(BrdfcodecError):
    """A weight file's SHA-256 differs from its manifest: the file is corrupt or not the named model."""


class ModelFolderError(FileFormatError):
    """A model folder (``spec/model.md`` §3) that cannot be used: a ``model.json`` outside its schema or
    bounds, a file that is not a regular file inside the folder or is too large, weights whose names,
    shapes, values or stored config differ from the manifest's."""


class CheckpointError(FileFormatError):
    """A training checkpoint (``best.pt``, ``checkpoint.pt``) that is unreadable, holds anything but tensors
    and plain values (a pickle that would run code is refused unread), or lacks what training stored."""
class OptionalDependencyError(BrdfcodecError, ImportError):
    """An optional extra this operation needs is not installed; the message names the pip command."""
class RateTargetError(BrdfcodecError, ValueError):
    """A size budget or error target that no layered record of a material can meet (issue 14 rate control)."""
