"""brdfcodec: measured BRDFs as a tiny, editable β-VAE latent code.

The light core (MERL I/O, coordinates, transforms, metrics) is importable
from here; datasets (:mod:`brdfcodec.dataset`, needs h5py) and analytic or
proxy sources live in their own modules. The codec (:mod:`brdfcodec.codec`,
needs torch) is loaded on first use of ``compress``, ``decompress``,
``BrdfEncoder``, ``BrdfDecoder`` or ``MaterialLibrary``, so that importing
brdfcodec and reading ``.bvae`` headers stays fast.
"""

from typing import Any

from brdfcodec.bvae_format import (
    BvaeReader,
    DecoderReference,
    GraftRecord,
    LatentRecord,
    read_bvae,
    read_header,
    write_bvae,
)
from brdfcodec.errors import (
    BrdfcodecError,
    BvaeChecksumError,
    BvaeFormatError,
    DatasetError,
    DecoderMismatchError,
    DecoderNotFoundError,
    FileFormatError,
    LatentDimensionError,
    MerlFormatError,
    NonFiniteValueError,
    SourceFormatError,
    UnmeasuredMaterialError,
    UnsupportedVersionError,
)
from brdfcodec.genuine import genuine_merl_name
from brdfcodec.lookup import lookup
from brdfcodec.merl import MerlBRDF, read_merl, write_merl
from brdfcodec.metrics import cosine_weighted_rmse, error_report, relae_linear, relae_mapped
from brdfcodec.transforms import interpolate_slices, map_values, select_kept_slices, unmap_values
from brdfcodec.version import __version__

_CODEC_NAMES = ("BrdfDecoder", "BrdfEncoder", "DecodedMaterial", "MaterialLibrary", "compress", "decompress")


def __getattr__(name: str) -> Any:
    if name in _CODEC_NAMES:
        from brdfcodec import codec

        return getattr(codec, name)
    raise AttributeError(f"module 'brdfcodec' has no attribute {name!r}")


__all__ = [
    "BrdfDecoder",
    "BrdfEncoder",
    "BvaeChecksumError",
    "BvaeFormatError",
    "BvaeReader",
    "DecodedMaterial",
    "DecoderMismatchError",
    "DecoderNotFoundError",
    "DecoderReference",
    "GraftRecord",
    "LatentDimensionError",
    "LatentRecord",
    "MaterialLibrary",
    "UnsupportedVersionError",
    "compress",
    "decompress",
    "read_bvae",
    "read_header",
    "write_bvae",
    "BrdfcodecError",
    "DatasetError",
    "FileFormatError",
    "MerlBRDF",
    "MerlFormatError",
    "NonFiniteValueError",
    "SourceFormatError",
    "UnmeasuredMaterialError",
    "__version__",
    "cosine_weighted_rmse",
    "error_report",
    "genuine_merl_name",
    "interpolate_slices",
    "lookup",
    "map_values",
    "read_merl",
    "relae_linear",
    "relae_mapped",
    "select_kept_slices",
    "unmap_values",
    "write_merl",
]
