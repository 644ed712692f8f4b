"""The albedo quadrature against a dense reference on sharp tables (issue 50, 2; spec/conventions.md §11).

A judge with 295,000 stratified directions found an edit of directional albedo 1.047 that the energy bound had
passed: the bound's quadrature under-counted sharp lobes. The reference here integrates the same nearest-bin
lookup over ≥ 10⁵ outgoing directions per incident angle, stratified and jittered, in two parts that partition
the hemisphere: a fine polar grid around the mirror direction (where sharp lobes are) and a cosine-weighted grid
elsewhere. It shares with the quadrature only the bin lookup (spec/conventions.md §3).
"""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.codec import BrdfDecoder
from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.edit.latent_edits import with_parameters
from brdfcodec.examples import example_library
from brdfcodec.representation import reflectance_from_stored, stored_from_reflectance
from brdfcodec.representation.coords import half_diff_from_directions, phi_d_index, theta_d_index, theta_h_index
from brdfcodec.representation.energy import ALBEDO_THETA_I_DEG, directional_albedo
from brdfcodec.representation.mask import horizon_mask

#: Relative agreement asked of the quadrature (issue 50: 0.1 %).
RELATIVE = 1e-3
#: Half-angle (rad) of the cone around the mirror direction sampled finely by the reference.
_CONE = 0.12


def _lookup(reflectance: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Nearest-bin reflectance (3, n) of direction pairs; 0 below the horizon or the surface."""
    theta_h, theta_d, phi_d, _ = half_diff_from_directions(np.broadcast_to(wi, wo.shape), wo)
    h, d, p = theta_h_index(theta_h), theta_d_index(theta_d), phi_d_index(phi_d)
    valid = horizon_mask()[h, d, p] & (wo[:, 2] > 0)
    return np.where(valid, reflectance[:, h, d, p], 0.0)


def dense_albedo(reflectance: np.ndarray, theta_i_deg: float, per_part: int = 600, seed: int = 0) -> np.ndarray:
    """Directional albedo (3,) by a stratified, jittered reference of 2·per_part² outgoing directions."""
    rng = np.random.default_rng(seed)
    ti = np.radians(theta_i_deg)
    wi = np.array([np.sin(ti), 0.0, np.cos(ti)])
    mirror = np.array([-wi[0], 0.0, wi[2]])
    grid = (np.stack(np.meshgrid(np.arange(per_part), np.arange(per_part), indexing="ij"), -1).reshape(-1, 2)
            + rng.random((per_part**2, 2))) / per_part
    # Part 1: the cone of half-angle _CONE around the mirror direction, polar angle α = _CONE·v² (dense near
    # the peak), azimuth uniform; dω = sin α dα dβ; 16× more strata in v than in β (a lobe's edge is a circle).
    n_v, n_b = 4 * per_part, per_part // 4
    cells = np.stack(np.meshgrid(np.arange(n_v), np.arange(n_b), indexing="ij"), -1).reshape(-1, 2)
    v = (cells[:, 0] + rng.random(len(cells))) / n_v
    alpha, beta = _CONE * v**2, 2 * np.pi * (cells[:, 1] + rng.random(len(cells))) / n_b
    e1 = np.cross(mirror, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(mirror, e1)
    wo = (np.cos(alpha)[:, None] * mirror + np.sin(alpha)[:, None]
          * (np.cos(beta)[:, None] * e1 + np.sin(beta)[:, None] * e2))
    jacobian = np.sin(alpha) * (2 * _CONE * v) * 2 * np.pi / per_part**2
    cone = (_lookup(reflectance, wi, wo) * np.clip(wo[:, 2], 0, None) * jacobian).sum(axis=1)
    # Part 2: the rest of the hemisphere, cosine-weighted (pdf cos θo / π), the cone's directions left out.
    r, phi = np.sqrt(grid[:, 0]), 2 * np.pi * grid[:, 1]
    wo = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.clip(1 - grid[:, 0], 0, None))], axis=-1)
    outside = wo @ mirror < np.cos(_CONE)
    rest = (_lookup(reflectance, wi, wo) * outside).sum(axis=1) * np.pi / per_part**2
    return cone + rest


def _spike_table(value: float = 1e6) -> np.ndarray:
    """The red-team's spike: stored value ``value`` in θh bins 0–1 (every θd, φd), 0 elsewhere."""
    table = np.zeros((3, 90, 90, 180))
    table[:, :2] = value
    return table


def _chrome_table() -> np.ndarray:
    return ANALYTIC_PRESETS["chrome"].to_merl().values


SHARP = {"chrome": _chrome_table, "spike-theta-h-0-1": _spike_table}


@pytest.mark.parametrize("name", sorted(SHARP))
@pytest.mark.slow
def test_the_quadrature_matches_a_dense_reference_on_sharp_tables(name: str) -> None:
    """Four incident angles of the bound (all 13: the slow test below), 720,000 directions each."""
    table = SHARP[name]()
    reflectance = reflectance_from_stored(table)
    albedo = directional_albedo(table)
    # The spike's grazing sliver is where the reference itself wavers by ±0.2 % at this density: the slow test.
    for theta_i in (0.0, 30.0, 60.0, 80.0) if name == "chrome" else (0.0, 30.0, 60.0):
        row = ALBEDO_THETA_I_DEG.index(theta_i)
        reference = dense_albedo(reflectance, theta_i, per_part=600)
        scale = max(float(reference.max()), 1e-12)
        np.testing.assert_allclose(albedo[row], reference, rtol=0, atol=RELATIVE * scale,
                                   err_msg=f"{name} at θi = {ALBEDO_THETA_I_DEG[row]}°")


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SHARP))
def test_the_quadrature_matches_a_denser_reference_at_every_angle(name: str) -> None:
    """All 13 incident angles, 2,000,000 directions each (the reference's own error near grazing is about
    0.25 % at 320,000 directions, below 0.01 % here)."""
    table = SHARP[name]()
    reflectance = reflectance_from_stored(table)
    albedo = directional_albedo(table)
    references = [dense_albedo(reflectance, theta_i, per_part=1000, seed=1) for theta_i in ALBEDO_THETA_I_DEG]
    # the bound reads the largest albedo over the angles: each angle's error is measured against it (the spike's
    # albedo at 87.5° is 1e-5, where the reference's own 0.4 % sampling spread is 1e-4 of the largest)
    scale = max(max(float(reference.max()) for reference in references), 1e-12)
    for row, (theta_i, reference) in enumerate(zip(ALBEDO_THETA_I_DEG, references, strict=True)):
        np.testing.assert_allclose(albedo[row], reference, rtol=0, atol=RELATIVE * scale, err_msg=f"θi = {theta_i}°")


def test_a_lambertian_table_still_integrates_to_its_albedo() -> None:
    table = stored_from_reflectance(np.broadcast_to((np.array([0.2, 0.5, 0.9]) / np.pi)[:, None, None, None],
                                                    (3, 90, 90, 180)).copy())
    np.testing.assert_allclose(directional_albedo(table)[:-3], np.broadcast_to([0.2, 0.5, 0.9], (10, 3)), rtol=2e-3)


@pytest.mark.slow  # 2,000,000 reference directions at three angles
def test_a_sharp_edit_decodes_within_the_bound_by_the_dense_reference() -> None:
    """Chrome at z4 −3σ (a lobe the network makes far too bright), bounded: no albedo above 1.001 by the
    reference at the angles where the raw decode is brightest."""
    import brdfcodec as bc

    decoder = BrdfDecoder()
    with bc.MaterialLibrary(example_library(), decoder=decoder) as library:
        chrome = library.record("chrome")
    z = np.asarray(chrome.mu, dtype=np.float32).copy()
    z[3] -= 3.0
    edited = with_parameters(chrome, z, name="chrome.z4-3", edit={"op": "traverse"})
    raw = decoder.decode(edited, masked="zero", energy_bound=False)
    assert float(directional_albedo(raw).max()) > 1.5  # the bound has work to do
    bounded = reflectance_from_stored(decoder.decode(edited, masked="zero"))
    rows = np.argsort(directional_albedo(raw).max(axis=1))[-3:]
    for row in rows:
        assert float(dense_albedo(bounded, ALBEDO_THETA_I_DEG[row], per_part=1000).max()) <= 1.001


@pytest.mark.slow  # computes the quadrature (several seconds of CPU)
def test_the_shipped_quadrature_is_the_computed_one() -> None:
    """The package ships the quadrature so that no process spends seconds building it before its first bounded
    decode; the file must hold exactly what the rule computes (``python -m brdfcodec.representation.energy``
    writes it anew after a change of the rule)."""
    from brdfcodec.representation import energy

    shipped = energy._shipped_quadrature()
    assert shipped is not None, f"brdfcodec/{energy.QUADRATURE_FILE} is missing or not of the current rule"
    for name, stored, computed in zip(("h", "d", "p", "weight", "row"), shipped, energy._computed_quadrature(),
                                      strict=True):
        np.testing.assert_array_equal(stored, computed, err_msg=f"shipped quadrature's {name} differs")


def test_the_quadrature_in_use_is_the_shipped_file(monkeypatch: pytest.MonkeyPatch) -> None:
    """A decode reads the shipped file instead of computing (the first bounded decode took seconds)."""
    from brdfcodec.representation import energy

    def computing() -> None:
        raise AssertionError("the quadrature was computed, not read from the shipped file")

    monkeypatch.setattr(energy, "_computed_quadrature", computing)
    energy._quadrature.cache_clear()
    try:
        used = energy._quadrature()
    finally:
        energy._quadrature.cache_clear()  # the next caller builds it again, from the file
    assert len(used) == 5 and len({len(array) for array in used}) == 1 and len(used[0]) > 0
