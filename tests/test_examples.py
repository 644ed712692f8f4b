"""The example library shipped in the package: it decodes with the shipped model, every material renders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from brdfcodec.codec import BrdfDecoder, MaterialLibrary
from brdfcodec.datasets.sources import nbrdf_zip_sources
from brdfcodec.examples import example_library
from brdfcodec.render.preview import render_sphere
from brdfcodec.representation.metrics import relae_mapped


@pytest.mark.slow
def test_every_shipped_material_decodes_and_renders_finite_and_non_negative() -> None:
    decoder = BrdfDecoder()
    with MaterialLibrary(example_library(), decoder=decoder) as library:
        assert len(library) == 90 and "green-acrylic" in library
        for name in library.names:
            material = library[name]
            image = render_sphere(material, size=24)
            assert np.isfinite(image).all() and (image >= 0).all() and image.max() > 0
            library.forget(name)  # keep memory flat: 90 decoded tables would be 1.6 GB
        assert library.decoded_count == 0


@pytest.mark.shared
@pytest.mark.slow  # > 10 s on 2 cores
def test_shipped_materials_match_their_sources(nbrdf_zip: Path) -> None:
    """Decode some materials of the library, measure them against the proxy tables they were made from."""
    with MaterialLibrary(example_library()) as library:
        for source in nbrdf_zip_sources(nbrdf_zip, ["green-acrylic", "gold-metallic-paint", "aluminium"]):
            brdf = source.load().brdf
            material = library[source.name]
            estimate = material.table(masked="keep").astype(np.float64)
            measured = relae_mapped(brdf.values, estimate, brdf.mask).overall
            assert measured < 0.2
            assert measured == pytest.approx(material.record.meta["relae"]["mapped"], rel=1e-3, abs=1e-4)
            library.forget(source.name)
