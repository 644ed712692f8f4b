"""White-furnace check of the example library: directional albedo of every material with the Mitsuba plug-in.

    python scripts/mitsuba_albedo.py            # prints the materials whose albedo exceeds 1

Albedo(θi) = ∫ f(ωi, ωo) cos θo dωo, estimated with the plug-in's own importance sampling (200,000 samples,
θi = 0°, 45°, 75°) in ``llvm_ad_rgb`` on the shipped example library (NBRDF proxy of MERL, default model).
"""

from __future__ import annotations

import math

import numpy as np


def main() -> None:
    from brdfcodec.examples import example_library
    from brdfcodec.format.bvae import read_header
    from brdfcodec.render import mitsuba_bsdf
    from brdfcodec.runtime import mitsuba as mitsuba_runtime

    mitsuba_runtime.set_variant("llvm_ad_rgb", fallback=None)
    import drjit as dr
    import mitsuba as mi

    mitsuba_bsdf.register()
    library = example_library()
    n = 200_000
    rng = np.random.default_rng(0)
    s1, s2 = mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))
    over = []
    for name in read_header(library).names:
        bsdf = mi.load_dict({"type": "bvae", "filename": str(library), "material": name})
        worst = 0.0
        for theta in (0.0, 45.0, 75.0):
            si = dr.zeros(mi.SurfaceInteraction3f, n)
            t = math.radians(theta)
            si.wi = mi.Vector3f(dr.full(mi.Float, math.sin(t), n), dr.zeros(mi.Float, n),
                                dr.full(mi.Float, math.cos(t), n))
            _, weight = bsdf.sample(mi.BSDFContext(), si, s1, s2)
            values = np.array(weight)
            albedo = (values if values.shape == (n, 3) else values.T).mean(axis=0)
            worst = max(worst, float(albedo.max()))
            if albedo.max() > 1.0:
                over.append((name, theta, albedo.round(3).tolist()))
        print(f"{name:28s} max albedo {worst:.3f}")
    print(f"\n{len({o[0] for o in over})} of {len(read_header(library).names)} materials exceed 1:")
    for row in over:
        print("  ", row)


if __name__ == "__main__":
    main()
