"""Analytic BRDFs and the NBRDF proxy evaluator."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from nbrdf_files import keras_description

from brdfcodec.conventions import MERL_COLOR_SCALE, UNMEASURED_VALUE
from brdfcodec.datasets.analytic import ANALYTIC_PRESETS, AnalyticBRDF, random_analytic_materials
from brdfcodec.datasets.nbrdf import iter_nbrdf_zip, list_nbrdf_zip, read_nbrdf_fit
from brdfcodec.errors import SourceFormatError
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.representation import map_values
from brdfcodec.representation.coords import directions_from_half_diff
from brdfcodec.representation.mask import horizon_mask


def test_presets_are_finite_valid_and_span_extremes(analytic_tables: dict[str, MerlBRDF]) -> None:
    maxima = {}
    for name, brdf in analytic_tables.items():
        assert np.isfinite(brdf.values).all(), name
        assert (brdf.values[:, ~horizon_mask()] == UNMEASURED_VALUE).all(), name
        assert (brdf.values[:, horizon_mask()] >= 0).all(), name
        maxima[name] = float(brdf.reflectance().max())
    assert maxima["chrome"] > 1e6  # a near-mirror with huge grazing values
    assert maxima["white-matte"] == pytest.approx(0.8 / np.pi)
    obsidian = analytic_tables["black-obsidian"]
    assert np.median(obsidian.reflectance()[:, obsidian.mask[0]], axis=1).max() < 0.01  # near-black off the peak


def test_lambert_is_constant_and_energy_conserving() -> None:
    material = AnalyticBRDF("white", diffuse=0.5, specular=0.0, roughness=1.0)
    wi, wo = directions_from_half_diff(0.3, 0.4, 1.0)
    np.testing.assert_allclose(material.evaluate(wi, wo), 0.5 / np.pi)


def test_ggx_lobe_is_reciprocal_and_peaks_at_the_mirror_direction() -> None:
    material = ANALYTIC_PRESETS["gold"]
    rng = np.random.default_rng(0)
    wi, wo = directions_from_half_diff(rng.uniform(0, 1.2, 50), rng.uniform(0, 1.2, 50), rng.uniform(0, 6, 50))
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    np.testing.assert_allclose(material.evaluate(wi[ok], wo[ok]), material.evaluate(wo[ok], wi[ok]), rtol=1e-12)
    mirror = material.evaluate(*directions_from_half_diff(0.0, 0.5, 0.0))
    off = material.evaluate(*directions_from_half_diff(0.3, 0.5, 0.0))
    assert (mirror > 10 * off).all()


def test_analytic_parameters_are_validated() -> None:
    with pytest.raises(ValueError, match="roughness"):
        AnalyticBRDF("x", roughness=0.0)
    with pytest.raises(ValueError, match="diffuse"):
        AnalyticBRDF("x", diffuse=(0.1, 0.2))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="specular"):
        AnalyticBRDF("x", specular=-0.1)


def test_random_materials_are_reproducible_and_independent_of_count() -> None:
    first = list(random_analytic_materials(5, seed=3))
    again = list(random_analytic_materials(8, seed=3))[:5]
    assert first == again
    assert first != list(random_analytic_materials(5, seed=4))
    assert len({m.name for m in random_analytic_materials(20)}) == 20


# --- NBRDF proxy ---------------------------------------------------------------------


def write_fit(path_or_buffer: Path | io.BytesIO, layers: list[tuple[np.ndarray, np.ndarray]]) -> None:
    with h5py.File(path_or_buffer, "w") as handle:
        for number, (kernel, bias) in enumerate(layers, start=1):
            group = handle.create_group(f"dense_{number}/dense_{number}")
            group["kernel:0"] = kernel.astype(np.float32)
            group["bias:0"] = bias.astype(np.float32)


def constant_fit(rgb: tuple[float, float, float]) -> list[tuple[np.ndarray, np.ndarray]]:
    """A network whose output is exp(log1p(rgb)) − 1 = rgb everywhere."""
    return [
        (np.zeros((6, 21)), np.zeros(21)),
        (np.zeros((21, 21)), np.zeros(21)),
        (np.zeros((21, 3)), np.log1p(np.asarray(rgb))),
    ]


def make_archive(tmp_path: Path, fits: dict[str, list[tuple[np.ndarray, np.ndarray]]]) -> Path:
    archive = tmp_path / "fits.zip"
    with zipfile.ZipFile(archive, "w") as handle:
        for name, layers in fits.items():
            buffer = io.BytesIO()
            write_fit(buffer, layers)
            handle.writestr(f"merl-nbrdf/{name}.h5", buffer.getvalue())
            handle.writestr(f"merl-nbrdf/{name}.json", keras_description())
        handle.writestr("merl-nbrdf/LICENSE", "MIT")
    return archive


def test_constant_fit_tabulates_to_its_constant(tmp_path: Path) -> None:
    archive = make_archive(tmp_path, {"grey": constant_fit((0.2, 0.3, 0.4)), "dark": constant_fit((0, 0, 0))})
    assert list_nbrdf_zip(archive) == ["dark", "grey"]
    grey = next(iter_nbrdf_zip(archive, ["grey"])).to_merl()
    physical = grey.reflectance()
    above = horizon_mask()
    expected = np.broadcast_to(np.array([0.2, 0.3, 0.4])[:, None], physical[:, above].shape)
    np.testing.assert_allclose(physical[:, above], expected, rtol=1e-6)
    assert (grey.values[:, ~above] == UNMEASURED_VALUE).all()


def test_fit_sees_half_and_difference_vectors_in_order(tmp_path: Path) -> None:
    """A probe network that outputs expm1 of (h_z, d_x, d_z): checks the order of the 6 inputs."""
    kernel = np.zeros((6, 21))
    kernel[2, 0] = kernel[3, 1] = kernel[5, 2] = 1.0  # h_z, d_x, d_z
    last = np.zeros((21, 3))
    last[0, 0] = last[1, 1] = last[2, 2] = 1.0
    layers = [(kernel, np.full(21, 0.0)), (np.eye(21), np.zeros(21)), (last, np.zeros(3))]
    path = tmp_path / "probe.h5"
    write_fit(path, layers)
    fit = read_nbrdf_fit(path)
    table = fit.to_merl().reflectance()
    i_h, i_d, i_p = 40, 30, 0
    theta_h = (i_h / 90) ** 2 * np.pi / 2
    theta_d = i_d / 90 * np.pi / 2
    expected = np.expm1([np.cos(theta_h), np.sin(theta_d), np.cos(theta_d)])
    np.testing.assert_allclose(table[:, i_h, i_d, i_p], expected, rtol=1e-5)


def test_negative_fit_outputs_are_clamped_to_zero(tmp_path: Path) -> None:
    archive = make_archive(tmp_path, {"under": constant_fit((-0.01, 0.1, 0.1))})
    brdf = next(iter_nbrdf_zip(archive)).to_merl()
    assert (brdf.reflectance()[0] == 0).all()
    assert brdf.mask[0, horizon_mask()].all()


def test_malformed_archives_and_fits(tmp_path: Path) -> None:
    not_zip = tmp_path / "x.zip"
    not_zip.write_bytes(b"hello")
    with pytest.raises(SourceFormatError, match="not a zip archive"):
        list_nbrdf_zip(not_zip)
    empty = tmp_path / "empty.zip"
    with zipfile.ZipFile(empty, "w") as handle:
        handle.writestr("README", "nothing")
    with pytest.raises(SourceFormatError, match="no NBRDF weight files"):
        list_nbrdf_zip(empty)
    wrong = constant_fit((0.1, 0.1, 0.1))
    wrong[1] = (np.zeros((21, 20)), np.zeros(20))
    archive = make_archive(tmp_path, {"wrong": wrong})
    with pytest.raises(SourceFormatError, match="dense_2"):
        next(iter_nbrdf_zip(archive))
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not hdf5 at all")
    with pytest.raises(SourceFormatError, match="not a readable HDF5"):
        read_nbrdf_fit(garbage)
    with pytest.raises(SourceFormatError, match="no material 'nope'"):
        next(iter_nbrdf_zip(archive, ["nope"]))


@pytest.mark.shared
def test_real_proxy_materials_look_like_merl(nbrdf_zip: Path) -> None:
    names = list_nbrdf_zip(nbrdf_zip)
    assert len(names) == 90 and "green-acrylic" in names and "chrome" in names
    fits = {fit.name: fit.to_merl() for fit in iter_nbrdf_zip(nbrdf_zip, ["green-acrylic", "chrome"])}
    green = fits["green-acrylic"].reflectance()
    above = horizon_mask()
    median_rgb = np.median(green[:, above], axis=1)  # the diffuse colour, away from the white highlight
    assert median_rgb[1] > median_rgb[0] and median_rgb[1] > median_rgb[2]  # it is green
    chrome = fits["chrome"]
    assert np.isfinite(chrome.values).all()
    assert chrome.reflectance().max() > 100  # a sharp specular peak
    assert map_values(chrome.values)[chrome.mask].max() < 5.0  # inside the mapped domain
    assert (chrome.values[:, above] >= 0).all()
    assert MERL_COLOR_SCALE[1] == pytest.approx(1.15 / 1500)
