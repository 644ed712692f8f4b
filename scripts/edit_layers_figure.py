"""Figure: an edit of a layered record keeps its detail (issue 41, part 6; docs/editing.md).

Compresses the analytic red plastic into 16 KB with the shipped model (a basis
and a detail layer), moves it along the roughness axis (z4 − 1.5σ: the model card's
z4 follows roughness and lowers the specular level with +z), and renders four spheres
under the same light and exposure: the original and the edit, each with its
layers and as its base alone. Prints the mapped RelAE of each against the
source table where there is one, the edit's distance from "edited base +
original layers" (zero by ``spec/bvae-format.md`` §4.4, "Edits"), and the
undo check::

    python scripts/edit_layers_figure.py docs/edit-layers.png
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from brdfcodec.codec import BrdfDecoder, DecodedMaterial, compress
from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
from brdfcodec.edit.latent_edits import traverse
from brdfcodec.format.bvae import LatentRecord, read_bvae
from brdfcodec.layers.layer_sum import layered_residual
from brdfcodec.render.images import auto_exposure, encode_srgb
from brdfcodec.representation import clamp_mapped
from brdfcodec.representation.metrics import relae_mapped

DIM, STEP, LIGHT = 3, -1.5, (-1.0, 1.0, 1.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", type=Path, help="PNG to write")
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from brdfcodec.render.preview import render_sphere

    source = ANALYTIC_PRESETS["red-plastic"].to_merl()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "rp.bvae"
        compress([source], path, names=["red-plastic"], bytes=16384, measure_error=False)
        size = path.stat().st_size
        record = read_bvae(path).records[0]
    decoder = BrdfDecoder()
    edited = traverse(record, DIM, [STEP])[0]
    base = LatentRecord("base", record.mu, record.sigma)
    edited_base = LatentRecord("edited-base", edited.mu, edited.sigma)

    def mapped(r: object) -> np.ndarray:
        return decoder.mapped_record(r)  # type: ignore[arg-type]

    residual = layered_residual(decoder.shared_basis, record.basis, record.detail)
    definition = clamp_mapped(decoder.decode_mapped(edited.mu) + residual)
    undone = traverse(edited, DIM, [-STEP])[0]
    print(f"record: {size:,} bytes")
    kept = decoder.mapped_record(edited, energy_bound=False)  # the layers' rule (§4.4); guard and bound after (§6)
    print(f"edited vs clamp(edited base + original layers): max |Δ| = {np.abs(kept - definition).max():.3g}")
    print(f"undone vs original: max |Δ| (mapped) = {np.abs(mapped(undone) - mapped(record)).max():.3g}")

    def error(r: object) -> float:
        return float(relae_mapped(source.values, DecodedMaterial(r, decoder).table()).overall)  # type: ignore[arg-type]

    def between(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.abs(a - b).sum() / np.abs(b).sum())

    panels = [
        (record, f"original, 16 KB layered\nRelAE vs source {error(record):.4f}"),
        (base, f"original, base only\nRelAE vs source {error(base):.4f}"),
        (edited, f"z{DIM + 1} {STEP:+g}σ, layers kept\n(edited base + original layers)"),
        (edited_base, f"z{DIM + 1} {STEP:+g}σ, edited base only\n"
                      f"{between(mapped(edited_base), mapped(edited)):.4f} from the kept edit (kept slices)"),
    ]
    images = [render_sphere(DecodedMaterial(r, decoder), size=256, light=LIGHT) for r, _ in panels]
    exposure = auto_exposure(images[0])
    figure, axes = plt.subplots(1, 4, figsize=(13, 3.9))
    for axis, image, (_, title) in zip(axes, images, panels, strict=True):
        axis.imshow(encode_srgb(image, exposure=exposure))
        axis.set_title(title, fontsize=9)
        axis.axis("off")
    figure.suptitle("Editing a layered record: the edit moves the base and keeps the layers", fontsize=11)
    figure.tight_layout()
    figure.savefig(args.output, dpi=90)
    print(f"wrote {args.output}")
    for _, title in panels:
        print(f"  {title.replace(chr(10), ' | ')}")


if __name__ == "__main__":
    main()
