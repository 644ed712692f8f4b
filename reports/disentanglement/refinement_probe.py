"""Base decode error at effort 0 and 1 (latent refinement) of the shipped model and the device models, on every
4th of the 120 training materials (NBRDF proxies), mapped RelAE over the full table; one JSON line per model and
effort on stdout. Run from the repository root with runs/both.h5 and the models of from_scratch_rows.py."""
import json
import time

import numpy as np

from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.representation.metrics import relae_mapped

models = {"v3": None, "w10k": "runs/models/dev1-w10k", "w0": "runs/models/dev1-w0", "w30k": "runs/models/dev1-w30k"}
with BrdfDataset("runs/both.h5") as d:
    idx = list(range(0, len(d), 4))
    tables = [(d.names[i], d.families[i], d.table(i)) for i in idx]
for label, folder in models.items():
    decoder = BrdfDecoder(folder)
    for effort in (0, 1):
        encoder = BrdfEncoder(folder, effort=effort)
        start = time.perf_counter()
        errs = {}
        for name, family, table in tables:
            record = encoder.encode(table, name=name)
            decoded = decoder.decode(record, masked="keep")
            errs.setdefault(family, []).append(relae_mapped(table.values, decoded, table.mask).overall)
        row = {"model": label, "effort": effort, "materials": len(tables),
               "relae_mapped": {f: float(np.mean(v)) for f, v in errs.items()},
               "all": float(np.mean([e for v in errs.values() for e in v])), "seconds": time.perf_counter() - start}
        print(json.dumps(row), flush=True)
