"""What RelAE values look like: source and decode side by side at several sizes (issue 39, 4).

For a few materials of the NBRDF proxy of MERL (and, with ``--rgl-zip``,
of the NBRDF proxy of RGL, which the shipped model never saw), encodes each at several
operating points (the encoder alone, 24 B, 64 B, 1 KB and 16 KB records,
float16 latents), measures the mapped and linear RelAE of the decode and
renders the source and the decode as spheres under one directional light
(same exposure). Writes ``levels.png`` (one row per material and level:
source left, decode right) and ``levels.json`` into the output folder.

    python scripts/relae_levels.py ../shared/data/merl-nbrdf-90.zip \
        --rgl-zip ../shared/data/rgl-nbrdf-30.zip -o reports/relae-levels
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


import brdfcodec as bc
from brdfcodec.codec import DecodedMaterial, measure
from brdfcodec.datasets.nbrdf import iter_nbrdf_zip
from brdfcodec.render.image_metrics import compare_images
from brdfcodec.render.images import auto_exposure, compose_sheet, encode_srgb, write_png
from brdfcodec.render.preview import render_sphere

#: (label, encoder options)
LEVELS = (
    ("encoder alone", {"effort": 0}),
    ("24 B", {"bytes": 24, "latent_dtype": "float16"}),
    ("64 B", {"bytes": 64, "latent_dtype": "float16"}),
    ("1 KB", {"bytes": 1024, "latent_dtype": "float16"}),
    ("16 KB", {"bytes": 16384, "latent_dtype": "float16"}),
)
MATERIALS = ("gold-metallic-paint", "red-fabric", "blue-acrylic")
RGL_MATERIALS = ("satin_blue_rgb", "paper_yellow_rgb")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("nbrdf_zip", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--rgl-zip", type=Path, help="also materials of the NBRDF proxy of RGL")
    parser.add_argument("--size", type=int, default=128)
    args = parser.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    encoders = {label: bc.BrdfEncoder(**options) for label, options in LEVELS}
    rows, labels, results = [], [], []
    fits = list(iter_nbrdf_zip(args.nbrdf_zip, list(MATERIALS)))
    if args.rgl_zip is not None:
        fits += list(iter_nbrdf_zip(args.rgl_zip, list(RGL_MATERIALS)))
    for fit in fits:
        source = fit.to_merl()
        reference = render_sphere(source, size=args.size)
        exposure = auto_exposure(reference)
        for label, encoder in encoders.items():
            record = measure(encoder.encode(source, name=fit.name), encoder.decoder, source)
            decoded = render_sphere(DecodedMaterial(record, encoder.decoder), size=args.size)
            delta = compare_images(reference, decoded, exposure=exposure).as_dict()
            relae = record.meta["relae"]
            results.append({"material": fit.name, "level": label, "relae_mapped": relae["mapped"],
                            "relae_linear": relae["linear"], **{f"image_{k}": v for k, v in delta.items()}})
            rows.append([encode_srgb(reference, exposure=exposure), encode_srgb(decoded, exposure=exposure)])
            labels.append(f"{fit.name}, {label}: mapped {relae['mapped']:.3f}, linear {relae['linear']:.3f}")
            print(labels[-1], flush=True)
    sheet = compose_sheet(rows, row_labels=labels, column_labels=["source (NBRDF proxy)", "decoded"],
                          title="RelAE and what it looks like (one directional light, same exposure)",
                          label_width=330)
    write_png(args.output / "levels.png", sheet, overwrite=True)
    from brdfcodec.report.rows import current_commit

    (args.output / "levels.json").write_text(json.dumps({
        "commit": current_commit(),
        "data": "NBRDF proxy of MERL (merl-nbrdf-90.zip)" + (", NBRDF proxy of RGL (rgl-nbrdf-30.zip)" if args.rgl_zip
                                                                else ""),
        "command": "python scripts/relae_levels.py ../shared/data/merl-nbrdf-90.zip --rgl-zip "
        "../shared/data/rgl-nbrdf-30.zip -o reports/relae-levels", "size": args.size, "rows": results}, indent=1)
        + "\n")


if __name__ == "__main__":
    main()
