"""Directional albedo and the energy bound (spec/conventions.md §11, spec/bvae-format.md §6 step 5; issue 41)."""

from __future__ import annotations

import numpy as np
import pytest

import brdfcodec as bc
from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.conventions import KEPT_PHI_D_SLICES
from brdfcodec.edit.latent_edits import traverse, with_parameters
from brdfcodec.edit.plausibility import UNPHYSICAL_TOLERANCE, measure_plausibility
from brdfcodec.examples import example_library
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.representation import network_input_from_table, stored_from_reflectance, table_from_mapped
from brdfcodec.representation.energy import (
    ALBEDO_THETA_I_DEG,
    directional_albedo,
    directional_albedo_mapped,
    energy_bound_scale,
    energy_bound_scale_mapped,
    scale_mapped,
)

BOUND = 1 + UNPHYSICAL_TOLERANCE


def _lambert(albedo: tuple[float, float, float]) -> np.ndarray:
    reflectance = np.asarray(albedo, dtype=np.float64)[:, None, None, None] / np.pi
    return stored_from_reflectance(np.broadcast_to(reflectance, (3, 90, 90, 180)).copy())


def _mapped(table: np.ndarray) -> np.ndarray:
    out = network_input_from_table(table)
    return np.asarray(out[0] if isinstance(out, tuple) else out)


@pytest.fixture(scope="module")
def decoder() -> BrdfDecoder:
    return BrdfDecoder()


@pytest.fixture(scope="module")
def chrome(decoder: BrdfDecoder) -> LatentRecord:
    with bc.MaterialLibrary(example_library(), decoder=decoder) as library:
        return library.record("chrome")


def test_a_lambertian_table_has_its_albedo_at_every_incident_angle() -> None:
    albedo = directional_albedo(_lambert((0.2, 0.5, 0.9)))
    assert albedo.shape == (len(ALBEDO_THETA_I_DEG), 3)
    np.testing.assert_allclose(albedo, np.broadcast_to([0.2, 0.5, 0.9], albedo.shape), atol=1e-3)


def test_the_kept_slices_give_the_same_albedo_as_the_decoded_table(analytic_tables) -> None:
    for name in ("gold", "chrome", "red-plastic", "black-obsidian"):
        mapped = _mapped(analytic_tables[name].values)
        from_table = directional_albedo(table_from_mapped(mapped))
        np.testing.assert_allclose(directional_albedo_mapped(mapped), from_table, rtol=1e-5, atol=1e-7)


def test_the_bound_brings_the_largest_albedo_to_one_and_leaves_conserving_tables_alone() -> None:
    bright = _lambert((1.5, 0.75, 0.3))
    scale = energy_bound_scale(bright)
    assert scale == pytest.approx(1 / 1.5, rel=1e-3)
    assert float(directional_albedo(bright * scale).max()) == pytest.approx(1.0, abs=1e-9)
    assert energy_bound_scale(_lambert((0.9, 0.9, 0.9))) == 1.0
    mapped = _mapped(bright)
    assert energy_bound_scale_mapped(mapped) == pytest.approx(energy_bound_scale(table_from_mapped(mapped)), rel=1e-5)


def test_a_factor_in_the_mapped_domain_is_the_same_factor_on_the_kept_bins() -> None:
    mapped = _mapped(_lambert((1.5, 0.75, 0.3)))
    kept = list(KEPT_PHI_D_SLICES)
    scaled = table_from_mapped(scale_mapped(mapped, 0.5), phi_d_bins=kept)
    np.testing.assert_allclose(scaled, 0.5 * table_from_mapped(mapped, phi_d_bins=kept), rtol=1e-5)
    np.testing.assert_array_equal(scale_mapped(mapped, 1.0), np.clip(mapped, 0, None))


def test_an_edit_decodes_bounded_and_the_raw_network_output_would_not_be(decoder, chrome) -> None:
    z = np.asarray(chrome.mu, dtype=np.float32).copy()
    z[3] -= 3.0  # chrome at z4 (roughness) −3σ: a sharper lobe the network makes far too bright
    edited = with_parameters(chrome, z, name="chrome.z4-3", edit={"op": "traverse"})
    raw = decoder.decode(edited, energy_bound=False)
    assert float(directional_albedo(raw).max()) > 1.5  # the case the bound exists for
    bounded = decoder.decode(edited)
    assert float(directional_albedo(bounded).max()) <= BOUND
    valid = (raw > 1e-3) & (np.arange(90) >= 2)[None, :, None, None]  # θh bins 0–1: the highlight guard's
    ratio = bounded[valid] / raw[valid]
    assert np.ptp(ratio) < 1e-4 * ratio.mean()  # one factor for every entry: colour and lobe shape kept
    partial = decoder.decode(edited, phi_d_bins=[0, 90, 179])
    np.testing.assert_array_equal(partial, bounded[..., [0, 90, 179]])
    mapped = decoder.mapped_record(edited)
    assert float(directional_albedo_mapped(mapped).max()) <= BOUND


def test_a_record_that_is_not_an_edit_decodes_as_encoded(decoder, chrome) -> None:
    np.testing.assert_array_equal(decoder.decode(chrome), decoder.decode(chrome, energy_bound=False))
    assert "edit" not in chrome.meta


@pytest.mark.slow
def test_traversals_of_materials_never_trained_on_conserve_energy(decoder, analytic_tables) -> None:
    """Every dimension at ±1, ±2, ±3σ of two analytic materials (no model here saw them), as edits decode: no
    directional albedo above 1 (issue 41)."""
    encoder = BrdfEncoder(effort=0)
    records = [encoder.encode(analytic_tables[name], name=name) for name in ("gold", "white-matte")]
    report = measure_plausibility(decoder, records)
    for kind in ("unphysical", "invalid"):
        assert float(report.fractions[kind].max()) == 0.0, kind
    raw = measure_plausibility(decoder, records, dims=(0, 1), energy_bound=False)
    assert raw.energy_bound is False and report.energy_bound is True
    assert float(raw.fractions["unphysical"].max()) > 0  # the network's own decodes do exceed 1 here
    for record in records:
        for edit in traverse(record, 0, [-3.0, 3.0]):
            assert float(directional_albedo(decoder.decode(edit)).max()) <= BOUND


@pytest.mark.slow  # about a minute on 2 cores
def test_traversals_of_materials_never_trained_on_keep_their_highlights(decoder) -> None:
    """Issue 41's bound on materials no model here saw: every dimension at ±1, ±2, ±3σ of 30 analytic materials
    (the 7 presets and 23 random ones of seed 0, as `reports/plausibility/default-model-analytic.txt` measures
    them), as edits decode: at most 3 % of the decodes have an inverted or holed highlight, none an albedo above 1."""
    from brdfcodec.datasets.sources import analytic_sources

    encoder = BrdfEncoder(effort=0)
    records = [encoder.encode(source.load().brdf, name=source.name) for source in analytic_sources(random_count=23)]
    report = measure_plausibility(decoder, records)
    assert len(report.materials) == 30
    assert float(report.fractions["highlight"].mean()) <= 0.03
    assert float(report.fractions["unphysical"].max()) == 0.0


@pytest.mark.slow
@pytest.mark.shared
def test_traversals_of_the_held_out_proxies_conserve_energy(decoder, nbrdf_zip, tmp_path) -> None:
    """Every dimension ±3σ of the stored split's held-out NBRDF proxies (v1 never saw them; v2 trained on every
    proxy): no directional albedo above 1."""
    from brdfcodec.cli.main import main

    library = tmp_path / "held-out.bvae"
    dataset = tmp_path / "proxy.h5"
    assert main(["dataset", "build", "--nbrdf-zip", str(nbrdf_zip), "-o", str(dataset), "--quiet"]) == 0
    assert main(["compress", str(dataset), "--split", "validation", "-o", str(library), "--no-measure"]) == 0
    with bc.MaterialLibrary(library, decoder=decoder) as opened:
        records = [opened.record(name) for name in opened.names]
    report = measure_plausibility(decoder, records)
    assert float(report.fractions["unphysical"].max()) == 0.0
