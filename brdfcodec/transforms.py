"""Deprecated home of the β-VAE's view of a table; everything lives in :mod:`brdfcodec.representation`.

Kept so that ``from brdfcodec.transforms import map_values`` and friends go on
working; ``network_input`` and ``from_network_input`` are the old names of
:func:`~brdfcodec.representation.to_network_layout` and
:func:`~brdfcodec.representation.from_network_layout`.
"""

from brdfcodec.representation.layout import from_network_layout as from_network_input
from brdfcodec.representation.layout import interpolate_slices, kept_slots_for_bins, select_kept_slices
from brdfcodec.representation.layout import to_network_layout as network_input
from brdfcodec.representation.mapping import map_values, unmap_values
from brdfcodec.representation.network_io import table_from_network_output

__all__ = [
    "from_network_input",
    "interpolate_slices",
    "kept_slots_for_bins",
    "map_values",
    "network_input",
    "select_kept_slices",
    "table_from_network_output",
    "unmap_values",
]
