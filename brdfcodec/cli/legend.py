"""The one-line legend that ``bvae`` prints under RelAE figures (what they measure, which to read)."""

from __future__ import annotations

__all__ = ["RELAE_LEGEND"]

#: Printed once under a command's RelAE figures (README, "Reading RelAE").
RELAE_LEGEND = (
    "RelAE: summed error of the decoded table over its source's, 0 = exact. Read 'mapped' (log-mapped values, "
    "close to what a render shows; the paper's models: 0.03-0.09); 'linear' weighs raw highlight peaks and runs "
    "far higher on shiny materials. README, \"Reading RelAE\"."
)
