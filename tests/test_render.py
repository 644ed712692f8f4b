"""Rendering helpers, image output, image-space metrics and the Mitsuba plug-in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from brdfcodec.codec import BrdfDecoder, DecodedMaterial, MaterialLibrary
from brdfcodec.datasets.analytic import AnalyticBRDF
from brdfcodec.edit.latent_edits import traverse
from brdfcodec.format.bvae import LatentRecord, write_bvae
from brdfcodec.io.exr import read_exr_rgb
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.render.image_metrics import compare_images
from brdfcodec.render.images import write_image
from brdfcodec.render.preview import Environment, render_flat, render_sphere, render_sphere_environment


@pytest.fixture(scope="module")
def lambert() -> MerlBRDF:
    return AnalyticBRDF("lambert", diffuse=(0.6, 0.4, 0.2), specular=(0.0, 0.0, 0.0), roughness=0.5).to_merl()


def test_lambertian_sphere_matches_the_closed_form(lambert: MerlBRDF) -> None:
    size = 64
    image = render_sphere(lambert, size=size, light=(0.0, 0.0, 1.0), irradiance=2.0)
    coords = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(coords, -coords)
    cos = np.sqrt(np.clip(1 - x * x - y * y, 0, None))
    expected = np.array([0.6, 0.4, 0.2]) / np.pi * 2.0 * cos[..., None]
    inner = (x * x + y * y) < 0.8
    np.testing.assert_allclose(image[inner], expected[inner], rtol=0.03)
    assert (image[(x * x + y * y) >= 1] == 0).all()


@pytest.mark.slow
def test_renders_of_decoded_materials_and_traversals_are_finite_and_non_negative() -> None:
    decoder = BrdfDecoder()
    rng = np.random.default_rng(0)
    base = LatentRecord("base", rng.normal(size=8), np.ones(8))
    for dim in range(8):
        for record in traverse(base, dim, [-3.0, 3.0]):
            image = render_sphere(DecodedMaterial(record, decoder), size=32)
            assert np.isfinite(image).all() and (image >= 0).all() and image.max() > 0


def test_environment_and_flat_renders(lambert: MerlBRDF) -> None:
    env_image = render_sphere_environment(lambert, size=24)
    flat = render_flat(lambert, size=24)
    for image in (env_image, flat):
        assert image.shape == (24, 24, 3) and np.isfinite(image).all() and (image >= 0).all() and image.max() > 0
    uniform = Environment.from_latlong(np.ones((16, 32, 3)))
    lit = render_sphere_environment(lambert, uniform, size=32)
    # a white furnace: a Lambertian sphere under uniform radiance 1 reflects its albedo (minus coarse sampling)
    centre = lit[16, 16]
    np.testing.assert_allclose(centre, [0.6, 0.4, 0.2], rtol=0.1)
    with pytest.raises(ValueError, match="non-negative"):
        Environment.from_latlong(-np.ones((16, 32, 3)))


def test_image_output(lambert: MerlBRDF, tmp_path: Path) -> None:
    image = render_sphere(lambert, size=16)
    write_image(tmp_path / "a.exr", image)
    np.testing.assert_array_equal(read_exr_rgb(tmp_path / "a.exr")[""], image)
    write_image(tmp_path / "a.png", image)
    from PIL import Image

    png = np.asarray(Image.open(tmp_path / "a.png"))
    assert png.shape == (16, 16, 3) and png.max() > 200
    with pytest.raises(FileExistsError):
        write_image(tmp_path / "a.png", image)
    with pytest.raises(ValueError, match="unknown image type"):
        write_image(tmp_path / "a.jpg", image)


def test_compare_images_metrics(lambert: MerlBRDF) -> None:
    reference = render_sphere(lambert, size=32)
    same = compare_images(reference, reference)
    assert same.delta_e_itp_mean == 0 and same.delta_e_2000_mean == 0 and same.psnr_db == float("inf")
    darker = compare_images(reference, reference * 0.9)
    much_darker = compare_images(reference, reference * 0.5)
    assert 0 < darker.delta_e_itp_mean < much_darker.delta_e_itp_mean
    assert 0 < darker.delta_e_2000_mean < much_darker.delta_e_2000_mean
    assert darker.psnr_db > much_darker.psnr_db
    tinted = reference.copy()
    tinted[..., 1] *= 1.2
    assert compare_images(reference, tinted).delta_e_itp_mean > 0


def test_mitsuba_plugin_matches_the_builtin_renderer(tmp_path: Path) -> None:
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is an optional extra: pip install 'brdfcodec[mitsuba]'")
    mi.set_variant("scalar_rgb")
    from brdfcodec.render import mitsuba_bsdf
    decoder = BrdfDecoder()
    path = tmp_path / "m.bvae"
    write_bvae(path, [LatentRecord("m", np.linspace(-0.5, 0.5, 8), np.ones(8))], decoder.reference)
    mitsuba_bsdf.register()
    size = 40
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            "type": "orthographic",
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
            "sampler": {"type": "stratified", "sample_count": 16},
        },
        "sphere": {"type": "sphere", "bsdf": {"type": "bvae", "filename": str(path), "material": "m"}},
        "light": {"type": "directional", "direction": [1, -1, -1], "irradiance": {"type": "rgb", "value": 1.0}},
    })
    rendered = np.array(mi.render(scene))
    with MaterialLibrary(path) as library:
        # Mitsuba integrates each pixel (16 stratified samples); supersample ours 4×4 to match.
        fine = render_sphere(library["m"], size=4 * size, light=(-1.0, 1.0, 1.0))
        reference = fine.reshape(size, 4, size, 4, 3).mean(axis=(1, 3))
    # Mitsuba's camera mirrors x relative to ours (its image x points to world -x when looking down -z).
    mitsuba_view = rendered[:, ::-1] if np.abs(rendered[:, ::-1] - reference).mean() < np.abs(
        rendered - reference).mean() else rendered
    coords = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(coords, -coords)
    inner = (x * x + y * y) < 0.85  # silhouette pixels are partly covered in Mitsuba
    relative = np.abs(mitsuba_view[inner] - reference[inner]).mean() / reference[inner].mean()
    assert relative < 0.05, relative
    np.testing.assert_allclose(mitsuba_view[inner].mean(axis=0), reference[inner].mean(axis=0), rtol=0.02)
