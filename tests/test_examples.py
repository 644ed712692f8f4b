"""The example library shipped in the package: it decodes with the shipped model, every material renders."""

from __future__ import annotations

import numpy as np

from brdfcodec.codec import BrdfDecoder, MaterialLibrary
from brdfcodec.examples import example_library
from brdfcodec.render import render_sphere


def test_every_shipped_material_decodes_and_renders_finite_and_non_negative() -> None:
    decoder = BrdfDecoder()
    with MaterialLibrary(example_library(), decoder=decoder) as library:
        assert len(library) == 90 and "green-acrylic" in library
        for name in library.names:
            material = library[name]
            assert 0 < material.record.meta["relae"]["mapped"] < 0.2
            image = render_sphere(material, size=24)
            assert np.isfinite(image).all() and (image >= 0).all() and image.max() > 0
            library.forget(name)  # keep memory flat: 90 decoded tables would be 1.6 GB
        assert library.decoded_count == 0
