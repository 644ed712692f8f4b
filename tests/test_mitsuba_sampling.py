"""The Mitsuba plug-in's importance sampling (issue 51): the luminance and VNDF warps of the material's RGL export.

* ``sample()``'s pdf is ``pdf()``, its weight is ``eval() / pdf()``, and the directions it draws follow ``pdf()``
  (Mitsuba's own χ² test at incident elevations on and between the warps' nodes);
* the warps are those :func:`brdfcodec.io.rgl_writer.rgl_fields` writes, non-negative, normalisable;
* a black material has none and is sampled by cosine; the warps' estimator has a lower variance than the
  θh-marginal mixture it replaced on a glossy material.

Needs a usable libLLVM (skipped with the reason otherwise). The materials are analytic presets written as MERL files.
Each Dr.Jit kernel compiles on first use (seconds on a busy machine): the cases beyond one per test are ``slow``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.io.merl import write_merl
from brdfcodec.runtime import mitsuba as mitsuba_runtime
from brdfcodec.runtime.mitsuba import LibLLVMNotFoundError

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is an optional extra: pip install 'brdfcodec[mitsuba]'")


@pytest.fixture(scope="module")
def llvm() -> str:
    try:
        variant = mitsuba_runtime.set_variant("llvm_ad_rgb", fallback=None)
    except (LibLLVMNotFoundError, RuntimeError) as error:
        pytest.skip(f"llvm_ad_rgb unavailable: {error}")
    from brdfcodec.render import mitsuba_bsdf

    mitsuba_bsdf.register()
    return variant


@pytest.fixture(scope="module")
def merl_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("sampling")
    paths = {}
    for name in ("gold", "red-plastic"):
        paths[name] = folder / f"{name}.binary"
        write_merl(paths[name], ANALYTIC_PRESETS[name].to_merl())
    return paths


@pytest.fixture(scope="module")
def bsdfs(llvm: str, merl_files: dict[str, Path]) -> dict[str, object]:
    """One loaded BSDF per material (kept alive, so that reloading one reuses its decoded table and warps)."""
    return {name: mi.load_dict({"type": "merl", "filename": str(path)}) for name, path in merl_files.items()}


def _interaction(theta_deg: float, n: int) -> object:
    """n copies of ωi at θ = theta_deg in the xz plane, as data (a literal would give every angle its own kernels)."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, n)
    theta = math.radians(theta_deg)
    si.wi = mi.Vector3f(np.full(n, math.sin(theta), np.float32), np.zeros(n, np.float32),
                        np.full(n, math.cos(theta), np.float32))
    return si


def _rows(values: object, n: int) -> np.ndarray:
    array = np.array(values)
    return array if array.shape == (n, 3) else array.T


def _sample(bsdf: object, theta_deg: float, n: int, seed: int = 0) -> tuple[object, np.ndarray, object]:
    rng = np.random.default_rng(seed)
    si = _interaction(theta_deg, n)
    bs, weight = bsdf.sample(mi.BSDFContext(), si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    return bs, _rows(weight, n), si


@pytest.mark.slow
def test_the_plugin_samples_by_the_warps(bsdfs: dict[str, object]) -> None:
    from brdfcodec.render.mitsuba_bsdf import WARP_COSINE_SHARE, material_of
    from brdfcodec.render.mitsuba_tables import SAMPLING_RESOLUTION as RES

    for bsdf in bsdfs.values():
        assert "luminance and VNDF warps" in str(bsdf) and f"{WARP_COSINE_SHARE:g} cosine" in str(bsdf)
        warps = material_of(bsdf).warps()
        assert warps.vndf.shape == (RES.theta_i, RES.vndf, RES.vndf)
        assert warps.luminance.shape == (RES.theta_i, RES.luminance, RES.luminance)
        for density in (warps.vndf, warps.luminance):
            assert np.isfinite(density).all() and density.min() >= 0 and (density.sum(axis=(1, 2)) > 0).all()
        np.testing.assert_allclose(warps.theta_i, np.linspace(0, np.pi / 2, RES.theta_i), atol=1e-6)


@pytest.mark.parametrize(("name", "theta_deg"), [
    ("gold", 37.0),
    *[pytest.param(name, theta, marks=pytest.mark.slow)
      for name, theta in [("gold", 0.0), ("gold", 75.0), ("red-plastic", 0.0), ("red-plastic", 37.0),
                          ("red-plastic", 75.0)]],
])
@pytest.mark.slow
def test_sample_weight_is_eval_over_pdf(bsdfs: dict[str, object], name: str, theta_deg: float) -> None:
    """For every sampled ωo: bs.pdf == pdf(ωo), weight == eval(ωo) / pdf(ωo), eval_pdf agrees."""
    bsdf = bsdfs[name]
    n = 100_000
    bs, weight, si = _sample(bsdf, theta_deg, n)
    ctx = mi.BSDFContext()
    sampled = np.array(bs.pdf)
    pdf = np.array(bsdf.pdf(ctx, si, bs.wo))
    value = _rows(bsdf.eval(ctx, si, bs.wo), n)
    value2, pdf2 = bsdf.eval_pdf(ctx, si, bs.wo)
    ok = sampled > 0
    assert ok.mean() > 0.8, ok.mean()  # reflections below the horizon are rejected (weight 0)
    assert np.isfinite(weight).all() and np.all(weight[~ok] == 0)
    np.testing.assert_allclose(sampled[ok], pdf[ok], rtol=2e-3)
    np.testing.assert_allclose(np.array(pdf2), pdf, rtol=1e-6)
    np.testing.assert_allclose(_rows(value2, n), value, rtol=1e-6)
    np.testing.assert_allclose(weight[ok], value[ok] / pdf[ok, None], rtol=2e-3, atol=1e-6)


@pytest.mark.parametrize("name", ["gold", "red-plastic"])
@pytest.mark.parametrize("theta_deg", [10.0, 50.0, 80.0])
@pytest.mark.slow
def test_sampled_directions_follow_the_pdf(llvm: str, bsdfs: dict[str, object], name: str, theta_deg: float,
                                           tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Mitsuba's χ² test: the histogram of sample()'s directions against pdf() integrated over each cell (24 × 24
    points a cell: with 8, the integral misses red-plastic's sharp lobe at 80° by 5 % in a cell, and the test fails)."""
    import drjit as dr
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain

    bsdf = bsdfs[name]
    theta = math.radians(theta_deg)
    wi = [math.sin(theta), 0.0, math.cos(theta)]

    def context(n: int) -> object:
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = wi
        return si

    def sample(u: object) -> tuple[object, object]:
        bs, _ = bsdf.sample(mi.BSDFContext(), context(dr.width(u)), u[0], mi.Point2f(u[1], u[2]))
        return bs.wo, dr.select(bs.pdf > 0, 1.0, 0.0)  # a direction is drawn wherever sample() returns one

    def pdf(wo: object) -> object:
        return bsdf.pdf(mi.BSDFContext(), context(dr.width(wo)), wo)

    monkeypatch.chdir(tmp_path)  # a rejected test writes chi2_data.py into the working folder
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=500_000, res=61, ires=24)
    assert test.run(significance_level=0.01), test.messages


@pytest.mark.parametrize("theta_deg", [60.0, pytest.param(20.0, marks=pytest.mark.slow)])
@pytest.mark.slow
def test_pdf_integrates_to_the_share_of_drawn_directions(bsdfs: dict[str, object], theta_deg: float) -> None:
    """∫ pdf dωo over the upper hemisphere (uniform Monte Carlo) equals the share of sample() calls that return a
    direction (the rest are reflections below the horizon), and is at most 1."""
    for bsdf in bsdfs.values():
        n = 400_000
        rng = np.random.default_rng(5)
        z, v = rng.random(n), rng.random(n)
        r = np.sqrt(1 - z * z)
        wo = mi.Vector3f(r * np.cos(2 * np.pi * v), r * np.sin(2 * np.pi * v), z)
        values = np.array(bsdf.pdf(mi.BSDFContext(), _interaction(theta_deg, n), wo)) * 2 * np.pi
        integral, error = values.mean(), 3 * values.std() / math.sqrt(n)
        bs, _, _ = _sample(bsdf, theta_deg, n)
        drawn = (np.array(bs.pdf) > 0).mean()
        assert integral <= 1.0 + error + 1e-3
        assert abs(integral - drawn) <= error + 3e-3, (str(bsdf), integral, error, drawn)


def test_warps_estimate_the_albedo_with_less_variance_than_the_theta_h_marginal(
        llvm: str, bsdfs: dict[str, object], merl_files: dict[str, Path]) -> None:
    """Gold at 40° (a glossy lobe): the warps' albedo estimator agrees with the θh-marginal one and has a lower
    variance (luminance of the sample weights)."""
    n = 200_000
    luminance = np.array([0.2126, 0.7152, 0.0722])
    old = mi.load_dict({"type": "merl", "filename": str(merl_files["gold"]), "sampling": "theta_h"})
    assert "θh marginal" in str(old)
    weights = {label: _sample(bsdf, 40.0, n, seed=2)[1] @ luminance
               for label, bsdf in (("warps", bsdfs["gold"]), ("theta_h", old))}
    means = {label: w.mean() for label, w in weights.items()}
    assert means["warps"] == pytest.approx(means["theta_h"], rel=0.02), means
    assert weights["warps"].var() < 0.5 * weights["theta_h"].var(), {k: w.var() for k, w in weights.items()}


def test_a_black_material_is_sampled_by_cosine(llvm: str, tmp_path: Path) -> None:
    from brdfcodec.render.mitsuba_tables import sampling_warps

    table = ANALYTIC_PRESETS["gold"].to_merl()
    black = np.where(table.values >= 0, 0.0, table.values)
    assert sampling_warps(black) is None
    table.values[...] = black
    path = tmp_path / "black.binary"
    write_merl(path, table)
    bsdf = mi.load_dict({"type": "merl", "filename": str(path)})
    assert "sampling=cosine" in str(bsdf)
    bs, weight, si = _sample(bsdf, 30.0, 1000)
    np.testing.assert_allclose(np.array(bs.pdf), np.array(bs.wo.z) / math.pi, rtol=1e-5)
    assert np.all(weight == 0)


def test_bad_sampling_is_a_clear_error(llvm: str, merl_files: dict[str, Path]) -> None:
    with pytest.raises(Exception, match="'sampling' must be tabulated, theta_h or cosine"):
        mi.load_dict({"type": "merl", "filename": str(merl_files["gold"]), "sampling": "vndf"})


def test_warps_built_after_the_host_table_is_dropped(llvm: str, merl_files: dict[str, Path]) -> None:
    """A float16 material first loaded with cosine sampling (the numpy table dropped after upload), then tabulated:
    the warps come from the renderer's copy (times its scale), and the numpy table stays dropped."""
    from brdfcodec.render.mitsuba_bsdf import material_of
    from brdfcodec.render.mitsuba_tables import load_physical, sampling_warps

    bsdf = {"type": "merl", "filename": str(merl_files["red-plastic"]), "precision": "float16"}
    cosine = mi.load_dict({**bsdf, "sampling": "cosine"})
    assert "sampling=cosine" in str(cosine) and material_of(cosine).values is None
    tabulated = mi.load_dict(bsdf)
    tables = material_of(tabulated)
    assert tables is material_of(cosine) and tables.values is None and "VNDF warps" in str(tabulated)
    direct = sampling_warps(load_physical(merl_files["red-plastic"])[1])
    np.testing.assert_allclose(tables.warps().luminance, direct.luminance, rtol=0.02, atol=1e-3)
