"""brdfcodec: measured BRDFs as a tiny, editable β-VAE latent code.

The light core is importable from here without torch: MERL I/O, the data
spine of :mod:`brdfcodec.representation` (stored ↔ reflectance, the log
mapping, kept slices, table ↔ network), lookup and metrics, and the
``.bvae`` format. Datasets (:mod:`brdfcodec.datasets.hdf5`, needs h5py) and
analytic or proxy sources live in their own modules. The codec
(:mod:`brdfcodec.codec`, needs torch) is loaded on first use of ``encode``,
``decode``, ``compress``, ``decompress``, ``BrdfEncoder``, ``BrdfDecoder``
or ``MaterialLibrary``, so that importing brdfcodec and reading ``.bvae``
headers stays fast.

>>> import brdfcodec as bc
>>> bc.reflectance_from_stored([[1500.0], [1500.0], [1500.0]]).ravel().round(2).tolist()
[1.0, 1.15, 1.66]
"""

from typing import Any

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
    ModelChecksumError,
    ModelNotFoundError,
    NoLatentError,
    NonFiniteValueError,
    OptionalDependencyError,
    SourceFormatError,
    UnmeasuredMaterialError,
    UnsupportedVersionError,
)
from brdfcodec.format.bvae import (
    BvaeReader,
    DecoderReference,
    GraftRecord,
    LatentRecord,
    read_bvae,
    read_header,
    write_bvae,
)
from brdfcodec.io.genuine import genuine_merl_name
from brdfcodec.io.inputs import read_measured
from brdfcodec.io.merl import MerlBRDF, read_merl, write_merl
from brdfcodec.representation import (
    interpolate_slices,
    map_values,
    network_input_from_table,
    reflectance_from_stored,
    select_kept_slices,
    stored_from_reflectance,
    table_from_network_output,
    unmap_values,
)
from brdfcodec.representation.lookup import lookup
from brdfcodec.representation.metrics import cosine_weighted_rmse, error_report, relae_linear, relae_mapped
from brdfcodec.runtime.threads import get_num_threads, set_num_threads
from brdfcodec.version import __version__

_CODEC_NAMES = (
    "BrdfDecoder",
    "BrdfEncoder",
    "ClampWarning",
    "DecodedMaterial",
    "MaterialInput",
    "MaterialLibrary",
    "compress",
    "decode",
    "decompress",
    "encode",
    "encode_records",
    "measure",
    "prepare_source",
)


def __getattr__(name: str) -> Any:
    if name in _CODEC_NAMES:
        from brdfcodec import codec

        return getattr(codec, name)
    raise AttributeError(f"module 'brdfcodec' has no attribute {name!r}")


__all__ = [  # the codec's names (loaded on first use, above) and the light core's
    *_CODEC_NAMES,
    "BrdfcodecError",
    "BvaeChecksumError",
    "BvaeFormatError",
    "BvaeReader",
    "DatasetError",
    "DecoderMismatchError",
    "DecoderNotFoundError",
    "DecoderReference",
    "FileFormatError",
    "GraftRecord",
    "LatentDimensionError",
    "LatentRecord",
    "MerlBRDF",
    "MerlFormatError",
    "ModelChecksumError",
    "ModelNotFoundError",
    "NoLatentError",
    "NonFiniteValueError",
    "OptionalDependencyError",
    "SourceFormatError",
    "UnmeasuredMaterialError",
    "UnsupportedVersionError",
    "cosine_weighted_rmse",
    "error_report",
    "genuine_merl_name",
    "get_num_threads",
    "interpolate_slices",
    "lookup",
    "map_values",
    "network_input_from_table",
    "read_bvae",
    "read_header",
    "read_measured",
    "read_merl",
    "reflectance_from_stored",
    "relae_linear",
    "relae_mapped",
    "select_kept_slices",
    "set_num_threads",
    "stored_from_reflectance",
    "table_from_network_output",
    "unmap_values",
    "write_bvae",
    "write_merl",
    "__version__",
]
