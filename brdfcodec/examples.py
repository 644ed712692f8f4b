"""Example data shipped with the package.

``nbrdf-proxy-90.bvae`` is a library of the 90 materials of the NBRDF proxy
of MERL (neural fits of MERL materials evaluated on the MERL grid; see the
documentation's data page, ``docs/data.md``), encoded by the shipped default
model's encoder alone: what ``bvae dataset build --nbrdf-zip
../shared/data/merl-nbrdf-90.zip -o merl90.h5 && bvae compress merl90.h5 -o
nbrdf-proxy-90.bvae --effort 0 --provenance`` gives (μ alone, no σ: format
2.2; ``source_sha256`` hashes of the dataset tables). Each record's metadata
holds its RelAE against the proxy table.
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
