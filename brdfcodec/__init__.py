"""brdfcodec: measured BRDFs as a tiny, editable β-VAE latent code.

The light core (MERL I/O, coordinates, transforms, metrics) is importable
from here; datasets (:mod:`brdfcodec.dataset`, needs h5py) and analytic or
proxy sources live in their own modules.
"""

from brdfcodec.errors import (
    BrdfcodecError,
    DatasetError,
    FileFormatError,
    MerlFormatError,
    NonFiniteValueError,
    SourceFormatError,
)
from brdfcodec.genuine import genuine_merl_name
from brdfcodec.lookup import lookup
from brdfcodec.merl import MerlBRDF, read_merl, write_merl
from brdfcodec.metrics import cosine_weighted_rmse, error_report, relae_linear, relae_mapped
from brdfcodec.transforms import interpolate_slices, map_values, select_kept_slices, unmap_values
from brdfcodec.version import __version__

__all__ = [
    "BrdfcodecError",
    "DatasetError",
    "FileFormatError",
    "MerlBRDF",
    "MerlFormatError",
    "NonFiniteValueError",
    "SourceFormatError",
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
