"""Checks of written RGL ``.bsdf`` files against Mitsuba 3's own ``measured`` BSDF (issue 38).

    python scripts/rgl_export_study.py                  # the five materials of the example scene
    python scripts/rgl_export_study.py --grid 64        # a finer RGB/luminance grid
    python scripts/rgl_export_study.py --no-render      # skip the scene renders
    python scripts/rgl_export_study.py --all --no-render  # also every material of the example library

For each material of the example scene (shipped example library: NBRDF proxy of MERL, default model), the
decoded table is written with :func:`brdfcodec.io.rgl_writer.write_rgl_bsdf` and loaded by ``measured``
(``llvm_ad_rgb``). Printed:

- write time of one material (seconds, this machine);
- RelAE of ``measured``'s eval (f cos θo) against the decoded table's lookup × cos θo at 200,000 pairs of
  directions uniform on the hemisphere (Σ|Δ| / Σ|ref| per channel), against the trilinear and the nearest
  lookup (the plug-in's default), and the RelAE of those two lookups against each other (the table's own
  interpolation ambiguity);
- χ² tests (Mitsuba's ``mitsuba.chi2``, 200,000 samples, 32 × 64 cells, ``ires`` 64: the
  pdf integrated on 64 × 64 points per cell, which glossy lobes need) at θi = 10°, 50°, 80°:
  ``measured.sample`` against ``measured.pdf`` (the reader's sampler is consistent), and against the
  luminance of ``measured.eval`` normalised over the sphere (how closely the sampler follows f cos θo);
- the round trip of the real RGL measurement ``paper_white_rgb.bsdf``: read (tabulated on the MERL grid)
  → write → read again, RelAE linear (bins with θi, θo < 80°), log-mapped and cosine-weighted (all bins);
- with ``--all``: every material of the example library written, loaded by ``measured`` and evaluated at
  50,000 pairs; the median, 90th percentile and maximum over materials of the worst channel's eval RelAE;
- the example scene rendered through the written files with ``measured`` and through the ``bvae`` plug-in
  (same seed and spp), mean and 95th-percentile ΔE ITP, and the plug-in against itself at another seed
  (the Monte Carlo noise floor).
"""

from __future__ import annotations

import argparse
import os
import re
import tempfile
import time
from pathlib import Path

import numpy as np

SCENE_MATERIALS = ("gold-metallic-paint", "chrome", "green-acrylic", "red-fabric", "blue-metallic-paint")


def _hemisphere(rng: np.random.Generator, n: int) -> np.ndarray:
    z, phi = rng.random(n), 2 * np.pi * rng.random(n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _eval(mi, bsdf, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:  # noqa: ANN001
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, wi.shape[0])
    si.wi = mi.Vector3f(*(wi[:, k].astype(np.float32) for k in range(3)))
    si.sh_frame = mi.Frame3f(mi.Normal3f(0, 0, 1))
    vec = mi.Vector3f(*(wo[:, k].astype(np.float32) for k in range(3)))
    return np.asarray(bsdf.eval(mi.BSDFContext(), si, vec), dtype=np.float64).T


def _relae(reference: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    return np.abs(reference - estimate).sum(axis=0) / np.abs(reference).sum(axis=0)


def _chi2(mi, path: Path, theta_deg: float, against_eval: bool) -> str:  # noqa: ANN001
    import drjit as dr
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    t = np.radians(theta_deg)
    wi = [float(np.sin(t)), 0.0, float(np.cos(t))]
    sample, pdf = BSDFAdapter("measured", {"type": "measured", "filename": str(path)}, wi=wi)
    if against_eval:
        bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
        weights = mi.Color3f(*[float(w) for w in (0.212671, 0.715160, 0.072169)])

        def lum(wo):  # noqa: ANN001, ANN202
            si = dr.zeros(mi.SurfaceInteraction3f, dr.width(wo))
            si.wi = mi.Vector3f(wi)
            value = bsdf.eval(mi.BSDFContext(), si, wo)
            return value[0] * weights[0] + value[1] * weights[1] + value[2] * weights[2]

        # normalise by a fine quadrature of the sphere (Fibonacci points)
        n = 4_000_000
        k = np.arange(n) + 0.5
        z = 1 - 2 * k / n
        phi = np.pi * (1 + 5**0.5) * k
        r = np.sqrt(1 - z * z)
        pts = mi.Vector3f(r * np.cos(phi), r * np.sin(phi), z)
        total = float(np.asarray(lum(pts)).sum()) * 4 * np.pi / n

        def pdf(wo, *args):  # noqa: ANN001, ANN002, ANN202, F811
            return lum(wo) / total

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=200_000, res=32, ires=64, seed=1)
    ok = test.run()
    stat = re.search(r"p-value = ([0-9.e+-]+)", test.messages)
    integral = re.search(r"PDF integrates to a value greater than 1.0: ([0-9.]+)", test.messages)
    detail = f"p={stat.group(1)}" if stat else (f"pdf quadrature {integral.group(1)} > 1" if integral else "n/a")
    return f"{'pass' if ok else 'FAIL'} ({detail})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=32, help="RGB/luminance samples per axis")
    parser.add_argument("--theta-i", type=int, default=32, help="incident elevations")
    parser.add_argument("--spp", type=int, default=256, help="samples per pixel of the scene renders")
    parser.add_argument("--no-render", action="store_true")
    parser.add_argument("--all", action="store_true", help="also every material of the example library")
    parser.add_argument("--shared", type=Path, default=Path(__file__).resolve().parents[2] / "shared")
    args = parser.parse_args()

    from brdfcodec.codec import MaterialLibrary
    from brdfcodec.examples import example_library
    from brdfcodec.io.rgl_writer import RglResolution, write_rgl_bsdf
    from brdfcodec.representation.lookup import lookup
    from brdfcodec.runtime.mitsuba import set_variant

    variant = set_variant(("llvm_ad_rgb",), fallback="scalar_rgb", warn=True)
    import mitsuba as mi

    print(f"Mitsuba {mi.__version__}, variant {variant}")
    resolution = RglResolution(theta_i=args.theta_i, luminance=args.grid)
    print(resolution)
    folder = Path(tempfile.mkdtemp(prefix="rgl-export-"))
    os.chdir(folder)  # a rejected χ² test writes chi2_data.py into the working folder
    rng = np.random.default_rng(0)
    wi, wo = _hemisphere(rng, 200_000), _hemisphere(rng, 200_000)
    cos_o = wo[:, 2:3]
    with MaterialLibrary(example_library()) as library:
        for name in SCENE_MATERIALS:
            material = library[name]
            table = material.table()
            start = time.perf_counter()
            path = write_rgl_bsdf(folder / f"{name}.bsdf", table, name=name, resolution=resolution)
            seconds = time.perf_counter() - start
            bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
            estimate = _eval(mi, bsdf, wi, wo)
            reflectance = np.asarray(material.reflectance(), dtype=np.float64)
            valid = np.broadcast_to(table >= 0, reflectance.shape)
            tri = lookup(reflectance, wi, wo, mode="trilinear", mask=valid) * cos_o
            near = lookup(reflectance, wi, wo, mode="nearest", mask=valid) * cos_o
            print(f"{name:22s} write {seconds:.2f} s, {path.stat().st_size / 1e6:.2f} MB; eval RelAE vs trilinear "
                  f"{np.round(_relae(tri, estimate), 3)}, vs nearest {np.round(_relae(near, estimate), 3)} "
                  f"(nearest vs trilinear {np.round(_relae(tri, near), 3)})")
            for theta in (10.0, 50.0, 80.0):
                print(f"    chi2 theta_i {theta:4.0f}: sample vs pdf {_chi2(mi, path, theta, False)}; "
                      f"sample vs lum(eval) {_chi2(mi, path, theta, True)}")

    source = args.shared / "data" / "rgl" / "paper_white_rgb.bsdf"
    if source.is_file():
        from brdfcodec.io.rgl import read_rgl_bsdf
        from brdfcodec.representation.coords import grid_direction_cosines
        from brdfcodec.representation.metrics import relae_linear, relae_mapped

        first = read_rgl_bsdf(source)
        path = write_rgl_bsdf(folder / "paper_white_rgb.bsdf", first.values, name="paper_white",
                              resolution=resolution)
        second = read_rgl_bsdf(path)
        cos_i, cos_oo = grid_direction_cosines()
        away = (first.values >= 0) & (np.minimum(cos_i, cos_oo) > np.cos(np.radians(80)))[None]
        weight = np.where(first.values >= 0, cos_i * cos_oo, 0.0)
        cosine = (np.abs(first.values - second.values) * weight).sum() / (np.abs(first.values) * weight).sum()
        away_relae = relae_linear(first.values, second.values, away).overall
        print(f"paper_white round trip: linear RelAE (θ < 80°) {away_relae:.4f}, "
              f"all bins {relae_linear(first.values, second.values).overall:.4f}; mapped "
              f"{relae_mapped(first.values, second.values).overall:.4f}; cosine-weighted {cosine:.4f}")
    else:
        print(f"paper_white round trip skipped: {source} not found")

    if args.all:
        _every_material(mi, folder, resolution)
    if not args.no_render:
        _render(mi, folder, args.spp)


def _every_material(mi, folder: Path, resolution) -> None:  # noqa: ANN001
    from brdfcodec.codec import MaterialLibrary
    from brdfcodec.examples import example_library
    from brdfcodec.io.rgl_writer import write_rgl_bsdf
    from brdfcodec.representation.lookup import lookup

    rng = np.random.default_rng(1)
    wi, wo = _hemisphere(rng, 50_000), _hemisphere(rng, 50_000)
    worst, seconds = {}, []
    every = folder / "all"
    every.mkdir()
    with MaterialLibrary(example_library()) as library:
        for name in library.names:
            material = library[name]
            table = material.table()
            start = time.perf_counter()
            path = write_rgl_bsdf(every / f"{name}.bsdf", table, name=name, resolution=resolution)
            seconds.append(time.perf_counter() - start)
            estimate = _eval(mi, mi.load_dict({"type": "measured", "filename": str(path)}), wi, wo)
            assert np.isfinite(estimate).all() and (estimate >= 0).all(), name
            reflectance = np.asarray(material.reflectance(), dtype=np.float64)
            valid = np.broadcast_to(table >= 0, reflectance.shape)
            reference = lookup(reflectance, wi, wo, mode="trilinear", mask=valid) * wo[:, 2:3]
            worst[name] = float(_relae(reference, estimate).max())
            library.forget(name)
    values = np.array(list(worst.values()))
    top = ", ".join(f"{n} {v:.3f}" for n, v in sorted(worst.items(), key=lambda kv: -kv[1])[:5])
    print(f"all {len(values)} materials loaded by measured (finite, non-negative eval); worst-channel eval RelAE "
          f"median {np.median(values):.3f}, p90 {np.percentile(values, 90):.3f}, max {values.max():.3f} ({top}); "
          f"write median {np.median(seconds):.2f} s, max {max(seconds):.2f} s")


def _render(mi, folder: Path, spp: int) -> None:  # noqa: ANN001
    from brdfcodec.examples import example_library
    from brdfcodec.render.image_metrics import compare_images
    from brdfcodec.render.mitsuba_scene import render_scene

    scene = Path(str(example_library())).parents[1] / "scenes" / "spheres.xml"
    text = scene.read_text()
    measured = re.sub(
        r'<bsdf type="bvae">\s*<string name="filename" value="\$library"/>\s*'
        r'<string name="material" value="([^"]+)"/>\s*</bsdf>',
        lambda m: f'<bsdf type="measured"><string name="filename" value="{folder}/{m.group(1)}.bsdf"/></bsdf>',
        text,
    )
    assert 'type="bvae"' not in measured
    measured_scene = folder / "spheres-measured.xml"
    measured_scene.write_text(measured)
    start = time.perf_counter()
    plugin, _ = render_scene(scene, spp=spp, seed=0, library=str(example_library()))
    plugin_s = time.perf_counter() - start
    noise, _ = render_scene(scene, spp=spp, seed=1, library=str(example_library()))
    start = time.perf_counter()
    builtin = np.asarray(mi.render(mi.load_file(str(measured_scene)), spp=spp, seed=0), dtype=np.float32)[..., :3]
    builtin_s = time.perf_counter() - start
    to_builtin = compare_images(plugin, builtin)
    floor = compare_images(plugin, noise)
    print(f"scene {spp} spp: measured vs bvae plug-in ΔE ITP mean {to_builtin.delta_e_itp_mean:.3f}, "
          f"p95 {to_builtin.delta_e_itp_p95:.3f}; plug-in seed 0 vs seed 1 (noise) mean {floor.delta_e_itp_mean:.3f}, "
          f"p95 {floor.delta_e_itp_p95:.3f}; render {plugin_s:.1f} s (plug-in) / {builtin_s:.1f} s (measured)")
    for label, image in (("plugin", plugin), ("measured", builtin)):
        np.save(folder / f"spheres-{label}.npy", image)
    print(f"renders and files kept in {folder}")


if __name__ == "__main__":
    main()
