"""Does green-channel grafting improve reconstruction? Encoder code vs refined 8-parameter code vs 10-parameter graft.

Usage::

    python scripts/graft_study.py DATASET.h5 [-o graft-study.json] [--materials NAME ...]

For each material (default: the green materials and the validation split of
the dataset), with the shipped model: the mapped RelAE of the encoder's code
(the network alone), of the code refined by gradient descent on the same 8
parameters (:func:`brdfcodec.edit.latent_edits.refine_code`), and of the fitted graft with
10 parameters (:func:`brdfcodec.edit.latent_edits.fit_graft`). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from brdfcodec.codec import BrdfDecoder, BrdfEncoder, measure
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.edit.latent_edits import fit_graft, refine_code
from brdfcodec.training.export import GREEN_MATERIALS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("-o", "--output", type=Path, default=Path("graft-study.json"))
    parser.add_argument("--materials", nargs="*")
    parser.add_argument("--steps", type=int, default=150)
    args = parser.parse_args()
    decoder, encoder = BrdfDecoder(), BrdfEncoder()
    rows = []
    with BrdfDataset(args.dataset) as dataset:
        names = args.materials or sorted(
            {n for n in GREEN_MATERIALS if n in dataset.names}
            | {dataset.names[i] for i in dataset.indices("validation")}
        )
        for name in names:
            index = dataset.index_of(name)
            brdf, inputs, mask = dataset.table(index), dataset.inputs([index])[0], dataset.input_masks([index])[0]
            start = time.perf_counter()
            [record] = encoder.encode_many([brdf], names=[name])
            refined = refine_code(decoder, record, inputs, mask, steps=args.steps)
            grafted = fit_graft(decoder, record, inputs, mask, steps=args.steps)
            row = {
                "material": name,
                "split": "validation" if index in dataset.indices("validation") else "train",
                "network": measure(record, decoder, brdf).meta["relae"]["mapped"],
                "refined_8": measure(refined, decoder, brdf).meta["relae"]["mapped"],
                "graft_10": measure(grafted, decoder, brdf).meta["relae"]["mapped"],
                "graft_values": grafted.graft_values.tolist(),
                "colour_dims": list(grafted.graft_dims),
                "seconds": time.perf_counter() - start,
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    from brdfcodec.report.rows import current_commit

    args.output.write_text(json.dumps({"commit": current_commit(), "data": str(args.dataset),
                                       "model": decoder.manifest.name, "rows": rows},
                                      indent=2))
    print("\n| material | split | network | refined, 8 parameters | graft, 10 parameters |\n|---|---|---|---|---|")
    for row in rows:
        print(f"| {row['material']} | {row['split']} | {row['network']:.4f} | {row['refined_8']:.4f} | "
              f"{row['graft_10']:.4f} |")


if __name__ == "__main__":
    main()
