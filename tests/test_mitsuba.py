"""Mitsuba 3 plug-in: libLLVM discovery, the vectorised BSDF against the scalar one and render_sphere, sampling,
energy, shared float16/float32 tables, scene references, ``bvae extract --scene`` and ``bvae render --mitsuba``.

The LLVM tests run wherever a usable libLLVM is found (CI installs libllvm19) and skip with the reason otherwise.
Images are small and sample counts low so that each test takes a few seconds on 2 cores.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.cli import main
from brdfcodec.codec import BrdfDecoder, MaterialLibrary
from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.examples import example_library
from brdfcodec.format.bvae import LatentRecord, read_header, write_bvae
from brdfcodec.io.merl import write_merl
from brdfcodec.render.preview import render_sphere
from brdfcodec.runtime import mitsuba as mitsuba_runtime
from brdfcodec.runtime.mitsuba import LibLLVMNotFoundError, find_libllvm, llvm_major

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is an optional extra: pip install 'brdfcodec[mitsuba]'")
SCENE = Path(__file__).resolve().parents[1] / "brdfcodec" / "data" / "scenes" / "spheres.xml"


# ---------------------------------------------------------------- libLLVM discovery (no Mitsuba variant needed)

def _fake_libs(folder: Path, names: list[str]) -> str:
    for name in names:
        (folder / name).write_bytes(b"\x7fELF")
    return str(folder / "libLLVM*")


def test_llvm_major_reads_debian_and_versioned_names() -> None:
    assert llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-14.0.6.so.1") == 14
    assert llvm_major("/usr/lib/llvm-18/lib/libLLVM.so") == 18
    assert llvm_major("/somewhere/libLLVM.so") is None


def test_find_libllvm_takes_the_newest_usable_and_skips_known_bad(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(mitsuba_runtime, "_SEARCH_GLOBS", ())
    monkeypatch.setattr(mitsuba_runtime, "_ldconfig_paths", lambda: [])
    pattern = _fake_libs(tmp_path, ["libLLVM-14.so", "libLLVM-15.so.1", "libLLVM.so.17.0", "libLLVM.so.19.1"])
    found = find_libllvm(extra_globs=[pattern], environ={})
    assert found.path.name == "libLLVM.so.19.1" and found.major == 19
    only_bad = tmp_path / "bad"
    only_bad.mkdir()
    with pytest.raises(LibLLVMNotFoundError, match="apt-get install libllvm19"):
        find_libllvm(extra_globs=[_fake_libs(only_bad, ["libLLVM-14.so", "libLLVM-15.so.1"])], environ={})


def test_find_libllvm_honours_and_checks_the_environment_variable(tmp_path: Path) -> None:
    _fake_libs(tmp_path, ["libLLVM-15.so.1", "libLLVM-custom.so"])
    named = find_libllvm(environ={"DRJIT_LIBLLVM_PATH": str(tmp_path / "libLLVM-custom.so")})
    assert named.source == "DRJIT_LIBLLVM_PATH" and named.major is None
    with pytest.raises(LibLLVMNotFoundError, match="libLLVM 15 does not work"):
        find_libllvm(environ={"DRJIT_LIBLLVM_PATH": str(tmp_path / "libLLVM-15.so.1")})
    with pytest.raises(LibLLVMNotFoundError, match="no such file"):
        find_libllvm(environ={"DRJIT_LIBLLVM_PATH": str(tmp_path / "missing.so")})


def test_set_variant_falls_back_with_a_warning() -> None:
    """A variant that cannot run here (no CUDA device in CI) gives the fallback and says why."""
    import drjit as dr

    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("a CUDA device is present")
    previous = mi.variant()
    try:
        with pytest.warns(mitsuba_runtime.MitsubaVariantWarning, match="cuda_ad_rgb: no CUDA device"):
            assert mitsuba_runtime.set_variant("cuda_ad_rgb") == "scalar_rgb"
        with pytest.raises(RuntimeError, match="no CUDA device"):
            mitsuba_runtime.set_variant("cuda_ad_rgb", fallback=None)
    finally:
        if previous is not None:
            mi.set_variant(previous)


# ---------------------------------------------------------------- fixtures

@pytest.fixture(scope="module")
def llvm() -> str:
    """Switch to llvm_ad_rgb (skip with the reason when no usable libLLVM exists)."""
    try:
        variant = mitsuba_runtime.set_variant("llvm_ad_rgb", fallback=None)
    except (LibLLVMNotFoundError, RuntimeError) as error:
        pytest.skip(f"llvm_ad_rgb unavailable: {error}")
    return variant


def _use(variant: str) -> None:
    from brdfcodec.render import mitsuba_bsdf
    mi.set_variant(variant)
    mitsuba_bsdf.register()


@pytest.fixture(scope="module")
def glossy_bvae(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-material library decoded by the default model (a plausible, moderately glossy material)."""
    path = tmp_path_factory.mktemp("mitsuba") / "m.bvae"
    write_bvae(path, [LatentRecord("m", np.linspace(-0.5, 0.5, 8), np.ones(8))], BrdfDecoder().reference)
    return path


@pytest.fixture(scope="module")
def analytic_tables() -> dict[str, object]:
    return {name: ANALYTIC_PRESETS[name].to_merl() for name in ("gold", "red-plastic", "white-matte")}


@pytest.fixture(scope="module")
def analytic_files(tmp_path_factory: pytest.TempPathFactory, analytic_tables) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("analytic")
    paths = {}
    for name, table in analytic_tables.items():
        paths[name] = folder / f"{name}.binary"
        write_merl(paths[name], table)
    return paths


def _sphere_scene(bsdf: dict, size: int, spp: int) -> object:
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            "type": "orthographic",
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
            "sampler": {"type": "stratified", "sample_count": spp},
        },
        "sphere": {"type": "sphere", "bsdf": bsdf},
        "light": {"type": "directional", "direction": [1, -1, -1], "irradiance": {"type": "rgb", "value": 1.0}},
    })


def _inner(size: int) -> np.ndarray:
    coords = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(coords, -coords)
    return (x * x + y * y) < 0.85  # silhouette pixels are partly covered in Mitsuba


def _ours(material, size: int) -> np.ndarray:
    """render_sphere supersampled 4×4 (Mitsuba integrates each pixel over its stratified samples)."""
    fine = render_sphere(material, size=4 * size, light=(-1.0, 1.0, 1.0))
    return fine.reshape(size, 4, size, 4, 3).mean(axis=(1, 3))


# ---------------------------------------------------------------- correctness of the vectorised plug-in

def test_llvm_plugin_matches_render_sphere(llvm: str, glossy_bvae: Path) -> None:
    """Stated tolerance: mean |Δ| under 3 % of the mean over interior pixels, mean colour within 2 %."""
    _use(llvm)
    size = 48
    rendered = np.array(mi.render(_sphere_scene({"type": "bvae", "filename": str(glossy_bvae)}, size, 16)))
    with MaterialLibrary(glossy_bvae) as library:
        reference = _ours(library["m"], size)
    inner = _inner(size)
    relative = np.abs(rendered[inner] - reference[inner]).mean() / reference[inner].mean()
    assert relative < 0.03, relative
    np.testing.assert_allclose(rendered[inner].mean(axis=0), reference[inner].mean(axis=0), rtol=0.02)


@pytest.mark.slow
def test_merl_plugin_renders_the_original_table(llvm: str, analytic_files: dict[str, Path], analytic_tables) -> None:
    _use(llvm)
    size = 40
    for bsdf in ({"type": "merl", "filename": str(analytic_files["red-plastic"])},
                 {"type": "bvae", "filename": str(analytic_files["red-plastic"])}):  # the filename switch
        rendered = np.array(mi.render(_sphere_scene(bsdf, size, 16)))
        reference = _ours(analytic_tables["red-plastic"], size)
        inner = _inner(size)
        assert np.abs(rendered[inner] - reference[inner]).mean() / reference[inner].mean() < 0.03


def _random_pairs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return v[0], v[1]


def test_llvm_plugin_matches_the_scalar_plugin_and_the_library(llvm: str, glossy_bvae: Path) -> None:
    """eval of 2,000 random direction pairs: the vectorised plug-in equals the scalar plug-in and
    brdfcodec.representation.lookup (nearest) on at least 99.5 % of them (float32 angles may cross a bin edge the float64
    ones do not), and within 1e-5 relative there."""
    wi, wo = _random_pairs(2000, 5)
    bsdf = {"type": "bvae", "filename": str(glossy_bvae)}
    scalar = _bsdf("scalar_rgb", bsdf)
    ctx = mi.BSDFContext()
    expected_scalar = []
    for a, b in zip(wi, wo, strict=True):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*a)
        expected_scalar.append(np.array(scalar.eval(ctx, si, mi.Vector3f(*b))) / b[2])
    vector = _bsdf(llvm, bsdf)
    si = _frame_wi(0.0, len(wi))
    si.wi = mi.Vector3f(*wi.T.astype(np.float32))
    got = _rows(vector.eval(ctx, si, mi.Vector3f(*wo.T.astype(np.float32))), len(wi)) / wo[:, 2:3]
    with MaterialLibrary(glossy_bvae) as library:
        expected_library = library["m"].eval(wi, wo)
    for expected in (np.array(expected_scalar), expected_library):
        same = np.all(np.abs(got - expected) <= 1e-5 * np.abs(expected) + 1e-7, axis=1)
        assert same.mean() >= 0.995, same.mean()
    assert np.isfinite(got).all() and (got >= 0).all()


@pytest.fixture(scope="module")
def noise_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """A MERL file of random values (unmeasured below the horizon and in 1 % of entries): any mistake in bins,
    corners or weights shows, where a smooth material would hide it."""
    from brdfcodec.io.merl import MerlBRDF
    from brdfcodec.representation.mask import horizon_mask

    rng = np.random.default_rng(11)
    values = rng.uniform(0.0, 1000.0, size=(3, 90, 90, 180))
    values[:, ~horizon_mask()] = -1.0
    values[rng.random(values.shape) < 0.01] = -1.0
    brdf = MerlBRDF(values, name="noise")
    path = tmp_path_factory.mktemp("noise") / "noise.binary"
    write_merl(path, brdf)
    return path, brdf


@pytest.mark.parametrize("mode", ["nearest", "trilinear"])
@pytest.mark.slow
def test_lookup_modes_match_the_library_on_noise(llvm: str, noise_file, mode: str) -> None:
    """Both lookups in llvm_ad_rgb equal brdfcodec.representation.lookup (with the file's mask) on a random table, on 2,000
    random pairs within 1e-3 relative: ≥ 99.9 % for trilinear (continuous, but steep where θh → 0), ≥ 99.5 %
    for nearest (float32 angles can cross a bin edge, which on noise changes the value); the scalar plug-in
    agrees likewise on 200."""
    path, brdf = noise_file
    wi, wo = _random_pairs(2000, 9)
    expected = brdf.eval(wi, wo, mode=mode)
    bsdf = {"type": "merl", "filename": str(path), "lookup": mode}
    vector = _bsdf(llvm, bsdf)
    si = _frame_wi(0.0, len(wi))
    si.wi = mi.Vector3f(*wi.T.astype(np.float32))
    got = _rows(vector.eval(mi.BSDFContext(), si, mi.Vector3f(*wo.T.astype(np.float32))), len(wi)) / wo[:, 2:3]
    share = 0.999 if mode == "trilinear" else 0.995
    same = np.all(np.abs(got - expected) <= 1e-3 * np.abs(expected) + 1e-6, axis=1)
    assert same.mean() >= share, same.mean()
    scalar = _bsdf("scalar_rgb", bsdf)
    rows = []
    for a, b in zip(wi[:200], wo[:200], strict=True):
        one = mi.SurfaceInteraction3f()
        one.wi = mi.Vector3f(*a)
        rows.append(np.array(scalar.eval(mi.BSDFContext(), one, mi.Vector3f(*b))) / b[2])
    same = np.all(np.abs(np.array(rows) - expected[:200]) <= 1e-3 * np.abs(expected[:200]) + 1e-6, axis=1)
    assert same.mean() >= share, same.mean()
    _use(llvm)


def _bsdf(variant: str, bsdf: dict) -> object:
    _use(variant)
    return mi.load_dict(bsdf)


def _frame_wi(theta_deg: float, n: int) -> object:
    """A surface interaction with n copies of ωi at θ = theta_deg in the xz plane."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, n)
    theta = math.radians(theta_deg)
    si.wi = mi.Vector3f(dr.full(mi.Float, math.sin(theta), n), dr.zeros(mi.Float, n),
                        dr.full(mi.Float, math.cos(theta), n))
    return si


def _rows(values: object, n: int) -> np.ndarray:
    """A Dr.Jit 3-vector array as (n, 3)."""
    array = np.array(values)
    return array if array.shape == (n, 3) else array.T


def _albedo(bsdf: object, theta_deg: float, n: int, seed: int = 0) -> tuple[np.ndarray, object, object]:
    """Directional albedo ∫ f cos dωo by the plug-in's own importance sampling (and the sampled directions)."""
    rng = np.random.default_rng(seed)
    si = _frame_wi(theta_deg, n)
    ctx = mi.BSDFContext()
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    return _rows(weight, n).mean(axis=0), bs, si


def _uniform_albedo(material, theta_deg: float, n: int, seed: int = 1) -> np.ndarray:
    """The same albedo by uniform hemisphere sampling of the library's own lookup (independent of the plug-in)."""
    rng = np.random.default_rng(seed)
    u, v = rng.random(n), rng.random(n)
    z = u
    r = np.sqrt(np.maximum(0, 1 - z * z))
    wo = np.stack([r * np.cos(2 * np.pi * v), r * np.sin(2 * np.pi * v), z], axis=-1)
    theta = math.radians(theta_deg)
    wi = np.array([math.sin(theta), 0.0, math.cos(theta)])
    return (material.eval(wi, wo) * z[:, None]).mean(axis=0) * 2 * np.pi


@pytest.mark.slow
def test_sampling_is_consistent_with_pdf_and_unbiased(llvm: str, analytic_files: dict[str, Path],
                                                      analytic_tables) -> None:
    """sample()'s pdf equals pdf(), and its albedo estimate equals an independent uniform-sampling one (gold, GGX
    α = 0.18: a glossy lobe)."""
    bsdf = _bsdf(llvm, {"type": "merl", "filename": str(analytic_files["gold"])})
    n = 400_000
    estimate, bs, si = _albedo(bsdf, 40.0, n)
    ctx = mi.BSDFContext()
    pdf = np.array(bsdf.pdf(ctx, si, bs.wo))
    sampled = np.array(bs.pdf)
    ok = sampled > 0
    assert ok.mean() > 0.8  # reflected half vectors below the horizon are rejected (weight 0)
    np.testing.assert_allclose(pdf[ok], sampled[ok], rtol=1e-4)
    reference = _uniform_albedo(analytic_tables["gold"], 40.0, 2_000_000)
    np.testing.assert_allclose(estimate, reference, rtol=0.03)


def test_pdf_integrates_to_the_share_of_valid_samples(llvm: str, glossy_bvae: Path) -> None:
    """∫ pdf dωo over the upper hemisphere equals the share of sample() calls that return a direction
    (the rest are reflections below the horizon): pdf() is the density sample() draws from."""
    bsdf = _bsdf(llvm, {"type": "bvae", "filename": str(glossy_bvae)})
    n = 400_000
    rng = np.random.default_rng(3)
    z, v = rng.random(n), rng.random(n)
    r = np.sqrt(1 - z * z)
    si = _frame_wi(30.0, n)
    wo = mi.Vector3f(r * np.cos(2 * np.pi * v), r * np.sin(2 * np.pi * v), z)
    integral = np.array(bsdf.pdf(mi.BSDFContext(), si, wo)).mean() * 2 * np.pi
    _, bs, _ = _albedo(bsdf, 30.0, n)
    valid_share = (np.array(bs.pdf) > 0).mean()
    assert integral <= 1.0 + 0.01
    assert integral == pytest.approx(valid_share, abs=0.015), (integral, valid_share)


@pytest.mark.slow
def test_furnace_albedo_at_most_one_for_plausible_materials(llvm: str, analytic_files: dict[str, Path]) -> None:
    """White-furnace check: directional albedo ≤ 1 for the analytic materials (energy-conserving by design)."""
    _use(llvm)
    for name, path in analytic_files.items():
        bsdf = mi.load_dict({"type": "merl", "filename": str(path)})
        for theta in (0.0, 45.0, 75.0):
            albedo, _, _ = _albedo(bsdf, theta, 100_000)
            assert np.all(albedo <= 1.0 + 0.02), (name, theta, albedo)
            assert np.all(albedo > 0.0)


def test_float16_tables_halve_memory_and_render_the_same(llvm: str, glossy_bvae: Path) -> None:
    from brdfcodec.render.mitsuba_bsdf import material_of

    _use(llvm)
    size = 24
    images, sizes = [], []
    for precision in ("float32", "float16"):
        scene = _sphere_scene({"type": "bvae", "filename": str(glossy_bvae), "precision": precision}, size, 4)
        images.append(np.array(mi.render(scene)))
        sizes.append(material_of(scene.shapes()[0].bsdf()).nbytes)
    assert sizes == [17_496_000, 8_748_000]
    assert material_of(scene.shapes()[0].bsdf()).values is None  # the numpy copy is dropped after upload
    assert np.abs(images[0] - images[1]).max() <= 2e-3 * images[0].max()


def test_shapes_share_one_decode_and_traverse_shows_the_table(llvm: str, glossy_bvae: Path, tmp_path: Path) -> None:
    from brdfcodec.render import mitsuba_tables
    from brdfcodec.render.mitsuba_scene import load_scene, material_memory

    other = tmp_path / "two.bvae"
    write_bvae(other, [LatentRecord("a", np.zeros(8), np.ones(8)), LatentRecord("b", np.full(8, 0.3), np.ones(8))],
               BrdfDecoder().reference)
    spheres = {f"s{i}": {"type": "sphere", "center": [2.5 * i, 0, 0],
                         "bsdf": {"type": "bvae", "filename": "two.bvae", "material": "ab"[i % 2]}} for i in range(4)}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"type": "scene", **spheres}))
    _use(llvm)
    before = mitsuba_tables.cache_info()["decodes"]
    scene = load_scene(path)
    assert mitsuba_tables.cache_info()["decodes"] - before == 2  # 4 spheres, 2 materials
    assert material_memory(scene) == {"a (float32)": 17_496_000, "b (float32)": 17_496_000}
    params = mi.traverse(scene)
    keys = [key for key in params.keys() if key.endswith("reflectance")]
    assert len(keys) == 2 and params[keys[0]].shape == (90 * 90 * 180 * 3,)  # one table per material


def test_bad_material_is_a_clear_error(llvm: str, glossy_bvae: Path) -> None:
    _use(llvm)
    with pytest.raises(Exception, match="no material named 'nope'"):
        mi.load_dict({"type": "bvae", "filename": str(glossy_bvae), "material": "nope"})
    with pytest.raises(Exception, match="precision"):
        mi.load_dict({"type": "bvae", "filename": str(glossy_bvae), "precision": "int8"})


# ---------------------------------------------------------------- scenes and the command line

def test_scene_materials_of_the_example_scene() -> None:
    from brdfcodec.render.mitsuba_scene import scene_materials

    references = scene_materials(SCENE)
    assert {r.filename for r in references} == {example_library().resolve()}
    assert [r.material for r in references] == ["gold-metallic-paint", "chrome", "green-acrylic", "red-fabric",
                                                "blue-metallic-paint", "chrome"]


@pytest.mark.slow
def test_example_scene_renders(llvm: str) -> None:
    """The shipped XML scene loads (relative library path, $parameters) and renders; its 6 spheres share 5 tables."""
    from brdfcodec.render.mitsuba_scene import material_memory, render_scene

    image, scene = render_scene(SCENE, spp=2, width=48, height=27)
    assert image.shape == (27, 48, 3) and np.isfinite(image).all() and image.mean() > 0
    assert len(material_memory(scene)) == 5


def test_extract_scene_keeps_exactly_the_referenced_materials(tmp_path: Path) -> None:
    out = tmp_path / "scene.bvae"
    assert main(["extract", "--scene", str(SCENE), "-o", str(out)]) == 0
    assert read_header(out).names == ["gold-metallic-paint", "chrome", "green-acrylic", "red-fabric",
                                      "blue-metallic-paint"]
    json_scene = tmp_path / "s.json"
    json_scene.write_text(json.dumps({"type": "scene", "a": {"type": "sphere", "bsdf": {
        "type": "bvae", "filename": str(example_library()), "material": "pvc"}}}))
    out2 = tmp_path / "json.bvae"
    assert main(["extract", str(example_library()), "--scene", str(json_scene), "-o", str(out2)]) == 0
    assert read_header(out2).names == ["pvc"]
    assert not (tmp_path / "bad.bvae").exists()
    assert main(["extract", "-o", str(tmp_path / "bad.bvae")]) == 2  # neither materials nor a scene: usage
    missing = tmp_path / "m.json"
    missing.write_text(json.dumps({"type": "scene", "a": {"type": "sphere", "bsdf": {
        "type": "bvae", "filename": str(example_library()), "material": "unobtainium"}}}))
    assert main(["extract", "--scene", str(missing), "-o", str(tmp_path / "bad.bvae")]) == 1
    assert not (tmp_path / "bad.bvae").exists()


@pytest.mark.slow
def test_render_mitsuba_command(llvm: str, tmp_path: Path, capsys) -> None:
    scene = tmp_path / "s.json"
    scene.write_text(json.dumps({
        "type": "scene",
        "sensor": {"type": "perspective", "to_world": {"look_at": {"origin": [0, 0, 4], "target": [0, 0, 0],
                                                                   "up": [0, 1, 0]}},
                   "film": {"type": "hdrfilm", "width": 32, "height": 32}},
        "light": {"type": "constant"},
        "a": {"type": "sphere", "bsdf": {"type": "bvae", "filename": str(example_library()), "material": "pvc",
                                         "precision": "float16"}},
    }))
    out = tmp_path / "s.png"
    assert main(["render", "--mitsuba", str(scene), "--spp", "4", "-o", str(out)]) == 0
    assert out.stat().st_size > 100
    assert "pvc (float16): 8.7 MB" in capsys.readouterr().out
    assert main(["render", "--mitsuba", str(tmp_path / "none.xml"), "-o", str(tmp_path / "x.png")]) == 1
    assert main(["render", "-o", str(tmp_path / "x.png")]) == 2  # neither IN nor a scene: usage
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps({"type": "scene", "a": {"type": "sphere", "bsdf": {"type": "bvae",
                                                                                    "filename": "missing.bvae"}}}))
    assert main(["render", "--mitsuba", str(broken), "-o", str(tmp_path / "y.png")]) == 1
    assert not (tmp_path / "y.png").exists()


# ---------------------------------------------------------------- original vs .bvae decode (shared data)

@pytest.mark.shared
@pytest.mark.slow
def test_original_and_decoded_material_in_one_scene_match_the_report(llvm: str, nbrdf_zip: Path,
                                                                     tmp_path: Path) -> None:
    """A material and its .bvae decode side by side in Mitsuba: ΔE ITP near the report's (NBRDF proxy of MERL).

    The report renders a 64² sphere under a directional light with render_sphere; the same set-up in Mitsuba
    (direct illumination, orthographic) must give the same ΔE ITP within 25 %.
    """
    from brdfcodec.datasets.nbrdf import iter_nbrdf_zip
    from brdfcodec.render.image_metrics import image_error

    name = "green-acrylic"
    row = next(json.loads(line) for line in (Path(__file__).resolve().parents[1] / "reports" / "nbrdf-proxy"
                                             / "materials.jsonl").read_text().splitlines()
               if json.loads(line)["material"] == name
               and json.loads(line)["point"] == "bvae-nbrdf-proxy-small-v1-float32")
    fit = next(iter_nbrdf_zip(nbrdf_zip, [name]))
    original = tmp_path / f"{name}.binary"
    write_merl(original, fit.to_merl())
    _use(llvm)
    size = 64
    images = [np.array(mi.render(_sphere_scene(bsdf, size, 16))) for bsdf in (
        {"type": "merl", "filename": str(original)},
        {"type": "bvae", "filename": str(example_library()), "material": name})]
    inner = _inner(size)
    error = image_error(np.where(inner[..., None], images[0], 0), np.where(inner[..., None], images[1], 0))
    print(f"{name}: Mitsuba ΔE ITP {error.delta_e_itp_mean:.3f}, report {row['delta_e_itp']:.3f}")
    assert error.delta_e_itp_mean == pytest.approx(row["delta_e_itp"], rel=0.25), (error, row["delta_e_itp"])
