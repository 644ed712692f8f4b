import numpy as np
from brdfcodec.codec import BrdfEncoder
from brdfcodec.dataset import BrdfDataset
from brdfcodec.metrics import error_report
with BrdfDataset("/work/data/both.h5") as ds:
    held = [i for i in ds.indices("validation") if ds.families[i] == "rgl"]
    print([ds.names[i] for i in held])
    for label, model in (("v1", None), ("both-mix09", "/work/models/both-mix09")):
        enc = BrdfEncoder(model, effort=0); dec = enc.decoder; vals = []
        for i in held:
            ref = ds.table(i)
            rec = enc.encode_arrays([ds.names[i]], ds.inputs([i]), ds.input_masks([i]), [None])[0]
            vals.append(error_report(ref.values, dec.decode(rec, masked="keep").astype(np.float64), ref.mask).relae_mapped.overall)
        print(label, np.round(vals, 4), round(float(np.mean(vals)), 4))
