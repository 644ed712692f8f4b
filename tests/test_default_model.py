"""The model shipped in the package: present, verified, well-behaved, and its card reproducible."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.conventions import MAPPED_MAX
from brdfcodec.datasets.sources import nbrdf_zip_sources
from brdfcodec.models.registry import default_model_folder, find_model
from brdfcodec.models.store import load_model
from brdfcodec.representation import table_from_network_output
from brdfcodec.representation.metrics import relae_mapped
from brdfcodec.training.measurements import traversal_changes


@pytest.fixture(scope="module")
def default_model():  # noqa: ANN201
    return load_model(default_model_folder())


def test_default_model_is_registered_and_verified(default_model) -> None:  # noqa: ANN001
    encoder, decoder, manifest = default_model
    assert find_model(manifest.decoder_sha256).folder == manifest.folder
    assert (manifest.folder / "decoder.safetensors").stat().st_size <= 10_000_000
    assert (manifest.folder / "MODEL_CARD.md").is_file()
    assert manifest.info["data"]["source_kind"] == "nbrdf-proxy"


@pytest.mark.parametrize("scale", [0.0, 3.0, 50.0])
def test_default_decoder_is_finite_for_extreme_latents(default_model, scale: float) -> None:  # noqa: ANN001
    _, decoder, manifest = default_model
    z = torch.randn(4, manifest.config.latent_dim, generator=torch.Generator().manual_seed(1)) * scale
    with torch.no_grad():
        out = decoder(z)
    assert torch.isfinite(out).all() and (out >= 0).all() and (out <= MAPPED_MAX).all()
    table = table_from_network_output(out.numpy())
    assert np.isfinite(table).all() and (table >= 0).all()


def test_every_latent_dimension_changes_the_material(default_model) -> None:  # noqa: ANN001
    """Traverse the shipped decoder now and compare with the card's traversal table."""
    _, decoder, manifest = default_model
    info = manifest.info
    measured = traversal_changes(decoder, np.asarray(info["latent_mean"], dtype=np.float32),
                                 np.maximum(np.asarray(info["latent_std"], dtype=np.float32), 1e-6))
    changes = [row["relative_change"] for row in measured]
    assert len(changes) == manifest.config.latent_dim and min(changes) > 0.01
    np.testing.assert_allclose(changes, [row["relative_change"] for row in info["traversal"]], rtol=1e-3)


@pytest.mark.shared
@pytest.mark.slow
def test_card_numbers_are_reproduced(nbrdf_zip: Path) -> None:
    """Re-measure some validation materials (and green-acrylic) from the proxy archive; compare with the card."""
    encoder, decoder = BrdfEncoder(effort=0), BrdfDecoder()  # the card measures the network's own posterior mean
    card = {row["name"]: row for row in encoder.manifest.info["errors"]}
    names = encoder.manifest.info["data"]["validation"][:4] + ["green-acrylic"]
    for source in nbrdf_zip_sources(nbrdf_zip, names):
        brdf = source.load().brdf
        [record] = encoder.encode_many([brdf])
        estimate = decoder.decode(record, masked="keep").astype(np.float64)
        measured = relae_mapped(brdf.values, estimate, brdf.mask).overall
        assert measured == pytest.approx(card[source.name]["relae_mapped"], rel=1e-3, abs=1e-4), source.name


@pytest.mark.parametrize("name", ["nbrdf-proxy-small-v1", "nbrdf-proxy-small-v2"])
def test_earlier_defaults_still_ship_and_are_found_by_their_decoder(name: str) -> None:
    """Files made with an earlier default name its decoder by hash: the package keeps it findable."""
    from brdfcodec.models.registry import package_model_folder
    from brdfcodec.models.store import load_manifest

    manifest = load_manifest(package_model_folder(name))
    assert manifest.name == f"bvae-{name}"
    assert find_model(manifest.decoder_sha256).folder == manifest.folder
    assert manifest.decoder_sha256 != load_manifest(default_model_folder()).decoder_sha256
