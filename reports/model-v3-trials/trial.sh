#!/usr/bin/env bash
# trial NAME INIT ARGS... : fine-tune, export aligned, compress, plausibility
set -u
n=$1; init=$2; shift 2
D=/work/runs/ft
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 BVAE_NUM_THREADS=1
cd /work/main && . /work/venv/bin/activate
bvae train runs/both.h5 -o $D/$n --init $init --quiet "$@" > $D/$n.log 2>&1 &&
bvae model export $D/$n -o $D/m-$n --name bvae-ft-$n --basis-count 0 --align-factors 300 >> $D/$n.log 2>&1 &&
bvae compress runs/both.h5 --model $D/m-$n -o $D/m-$n-lib.bvae --no-measure >> $D/$n.log 2>&1 &&
bvae model plausibility $D/m-$n --library $D/m-$n-lib.bvae --json > $D/m-$n-plaus.json 2>> $D/$n.log
python - $D/m-$n <<'PY'
import json, sys, numpy as np
d = sys.argv[1]
m = json.load(open(d + "/model.json"))["info"]
p = json.load(open(d + "-plaus.json"))["fractions"]
f = {k: float(np.mean(v)) for k, v in p.items()}
rot = np.array(m["alignment"]["rotation"])
print(d, "mapped_mean", round(m["summary"]["train"]["mapped_mean"], 5), "rot-dev", round(float(np.abs(rot - np.eye(len(rot))).max()), 3),
      {k: round(v, 4) for k, v in f.items()})
PY
