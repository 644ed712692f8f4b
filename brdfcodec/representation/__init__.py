"""The representation of a BRDF, on plain NumPy arrays (no torch): every conversion of the data spine.

::

    stored MERL values ──reflectance_from_stored──▶ reflectance (1/sr)
          │  ▲                                        (units)
          │  └─unmap_values── mapped ◀──map_values──  (mapping, spec §4)
          ▼
    network_input_from_table ──▶ (63, 90, 90) input + mask      (network_io, layout)
    network output ──clamp_mapped──▶ mapped ──table_from_mapped──▶ stored table
                                   (once)      (validate φd bins, interpolate §7, unmap)

Modules: :mod:`~brdfcodec.representation.units` (the colour scale),
:mod:`~brdfcodec.representation.mapping` (the log mapping and the clamp),
:mod:`~brdfcodec.representation.layout` (kept φd slices, channel layout,
interpolation), :mod:`~brdfcodec.representation.network_io` (table ↔
network). Constants are in :mod:`brdfcodec.conventions`.
"""

from brdfcodec.representation.layout import (
    BLUE_BLOCK,
    GREEN_BLOCK,
    RED_BLOCK,
    from_network_layout,
    interpolate_slices,
    kept_slots_for_bins,
    network_channel,
    network_channels_for_slots,
    select_kept_slices,
    to_network_layout,
    validate_phi_d_bins,
)
from brdfcodec.representation.mapping import LOG_RANGE, clamp_mapped, map_values, unmap_values
from brdfcodec.representation.network_io import (
    network_input_from_table,
    reflectance_from_mapped,
    table_from_mapped,
    table_from_network_output,
)
from brdfcodec.representation.units import channel_scale, reflectance_from_stored, stored_from_reflectance

__all__ = [
    "BLUE_BLOCK",
    "GREEN_BLOCK",
    "LOG_RANGE",
    "RED_BLOCK",
    "channel_scale",
    "clamp_mapped",
    "from_network_layout",
    "interpolate_slices",
    "kept_slots_for_bins",
    "map_values",
    "network_channel",
    "network_channels_for_slots",
    "network_input_from_table",
    "reflectance_from_mapped",
    "reflectance_from_stored",
    "select_kept_slices",
    "stored_from_reflectance",
    "table_from_mapped",
    "table_from_network_output",
    "to_network_layout",
    "unmap_values",
    "validate_phi_d_bins",
]
