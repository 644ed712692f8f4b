"""Example data shipped with the package.

``nbrdf-proxy-90.bvae`` is a library of the 90 materials of the NBRDF proxy
of MERL (neural fits of MERL materials evaluated on the MERL grid; see the
documentation's data page, ``docs/data.md``), encoded by the shipped default
model's encoder alone (written in format 1.0
before encode-time refinement existed: what ``bvae compress
merl-nbrdf-proxy.h5 -o nbrdf-proxy-90.bvae --effort 0 --provenance`` gives,
its ``source_sha256`` then hashes of the dataset tables; rewritten in format
2.0 with the same records and metadata). Each record's metadata holds its
RelAE against the proxy table.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["example_library"]


def example_library() -> Path:
    """Path of the shipped example library (90 NBRDF-proxy materials, default model).

    Raises
    ------
    FileNotFoundError
        The installation lacks it (a broken install).
    """
    path = Path(str(resources.files("brdfcodec").joinpath("data/libraries/nbrdf-proxy-90.bvae")))
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the example library is missing; reinstall brdfcodec")
    return path
