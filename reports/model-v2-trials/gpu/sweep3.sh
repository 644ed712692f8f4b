#!/bin/bash
# GPU sweep 3 (issue 12): the recipe and its 12-D variant, then per-family RelAE of each best.pt. Writes $OUT/res.tgz.
# Run from the repository root on the GPU machine; .devdata/ (git-ignored) held merl-nbrdf-90.zip, rgl-nbrdf-30.zip
# and whl/ (zstandard, OpenEXR and colour-science wheels for Python 3.12, which that machine lacked).
set -u
T0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .devdata/whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
W=/tmp/w; mkdir -p $W/runs $W/models $OUT/res
pack() { for k in "${!CFG[@]}"; do cp $W/runs/$k/log.jsonl $OUT/res/$k-log.jsonl 2>/dev/null; cp $W/runs/$k/summary.json $OUT/res/$k-summary.json 2>/dev/null; cp $W/runs/$k.log $W/models/$k.*.log $OUT/res/ 2>/dev/null; done; (cd $OUT && tar czf res.tgz res); }
python3 -m brdfcodec dataset build --nbrdf-zip .devdata/merl-nbrdf-90.zip --nbrdf-zip .devdata/rgl-nbrdf-30.zip -o $W/both.h5 --quiet > $OUT/res/build.log 2>&1 || { cat $OUT/res/build.log; exit 1; }
echo "build done $(( $(date +%s)-T0 ))"
R="--model small --mix-probability 0.9 --traversal-weight 10 --weight-decay 1.0 --quiet --eval-every 30"
declare -A CFG
CFG[r300]="$R"
CFG[z12]="$R --latent-dim 12"
for k in "${!CFG[@]}"; do
  OMP_NUM_THREADS=3 python3 -m brdfcodec train $W/both.h5 -o $W/runs/$k ${CFG[$k]} --time-limit 200 > $W/runs/$k.log 2>&1 &
done
wait
echo "train done $(( $(date +%s)-T0 ))"; pack
for k in "${!CFG[@]}"; do OMP_NUM_THREADS=4 timeout 60 python3 reports/model-v2-trials/family_eval.py $W/runs/$k $W/both.h5 > $OUT/res/$k-family.json 2>$W/models/$k.eval.log & done
wait
pack; rm -rf $OUT/res
echo "all done $(( $(date +%s)-T0 ))"
