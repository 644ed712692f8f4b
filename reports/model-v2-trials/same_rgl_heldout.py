"""Mapped RelAE of the shipped v1 model and of a trial model on the same held-out RGL materials.

Usage::

    python reports/model-v2-trials/same_rgl_heldout.py both.h5 models/both-mix09
"""

from __future__ import annotations

import argparse

import numpy as np

from brdfcodec.codec import BrdfEncoder
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.representation.metrics import error_report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", help="dataset with both families (bvae dataset build)")
    parser.add_argument("model", help="trial model folder (bvae model export)")
    args = parser.parse_args()
    with BrdfDataset(args.dataset) as dataset:
        held_out = [i for i in dataset.indices("validation") if dataset.families[i] == "rgl"]
        print([dataset.names[i] for i in held_out])
        for label, model in (("v1", None), (args.model, args.model)):
            encoder = BrdfEncoder(model, effort=0)
            errors = []
            for i in held_out:
                reference = dataset.table(i)
                record = encoder.encode_arrays([dataset.names[i]], dataset.inputs([i]), dataset.input_masks([i]),
                                               [None])[0]
                decoded = encoder.decoder.decode(record, masked="keep").astype(np.float64)
                errors.append(error_report(reference.values, decoded, reference.mask).relae_mapped.overall)
            print(label, np.round(errors, 4), round(float(np.mean(errors)), 4))


if __name__ == "__main__":
    main()
