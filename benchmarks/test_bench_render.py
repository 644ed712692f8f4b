"""Rendering and editing speed: a 256×256 sphere (decode timed apart), a traversal step, against baselines."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.codec import BrdfDecoder, DecodedMaterial
from brdfcodec.edit.latent_edits import interpolate, traverse
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.render.preview import render_sphere


@pytest.fixture(scope="module")
def material() -> DecodedMaterial:
    decoded = DecodedMaterial(LatentRecord("bench", np.linspace(-1, 1, 8), np.ones(8)), BrdfDecoder())
    decoded.reflectance()  # decode once: the render groups time rendering only
    return decoded


def test_render_baseline_full_decode(benchmark, material: DecodedMaterial) -> None:
    """Decoding the material (full table), the cost a first render pays once."""
    benchmark.group = "render-sphere-256"
    benchmark.extra_info["role"] = "baseline"
    benchmark(material.decoder.decode, material.record)


def test_render_sphere_256(benchmark, material: DecodedMaterial) -> None:
    """A 256×256 sphere under a directional light from an already decoded material."""
    benchmark.group = "render-sphere-256"
    benchmark.extra_info["role"] = "candidate"
    image = benchmark(render_sphere, material, size=256)
    assert image.shape == (256, 256, 3) and np.isfinite(image).all()


def test_edit_baseline_decode(benchmark, material: DecodedMaterial) -> None:
    benchmark.group = "edit-and-decode"
    benchmark.extra_info["role"] = "baseline"
    benchmark(material.decoder.decode, material.record)


def test_edit_then_decode(benchmark, material: DecodedMaterial) -> None:
    """A traversal step and an interpolation, then decoding the result: edits cost nothing next to decoding."""
    benchmark.group = "edit-and-decode"
    benchmark.extra_info["role"] = "candidate"
    other = LatentRecord("other", np.zeros(8), np.ones(8))

    def edit_and_decode() -> np.ndarray:
        edited = interpolate(traverse(material.record, 3, [1.5])[0], other, 0.3)
        return material.decoder.decode(edited)

    benchmark(edit_and_decode)
