#!/bin/bash
# GPU sweep 2 (issue 12): training set resident on the GPU. Writes $OUT/res.tgz.
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
CFG[r300s1]="$R --seed 1"
CFG[perm1]="$R --permute-colours 1.0"
CFG[z12]="$R --latent-dim 12"
CFG[r900]="$R --epochs 900 --eval-every 60"
for k in "${!CFG[@]}"; do
  OMP_NUM_THREADS=3 python3 -m brdfcodec train $W/both.h5 -o $W/runs/$k ${CFG[$k]} --time-limit 230 > $W/runs/$k.log 2>&1 &
done
wait
echo "train done $(( $(date +%s)-T0 ))"; pack
for k in "${!CFG[@]}"; do
  ( OMP_NUM_THREADS=3 timeout $(( 545 - ($(date +%s)-T0) )) python3 -m brdfcodec model export $W/runs/$k -o $W/models/$k --name bvae-gpu-$k-trial --basis-count 0 > $W/models/$k.export.log 2>&1 && echo "$k exported $(( $(date +%s)-T0 ))" &&
    OMP_NUM_THREADS=3 timeout $(( 545 - ($(date +%s)-T0) )) python3 -m brdfcodec model evaluate $W/models/$k --dataset $W/both.h5 --json > $OUT/res/$k-e0.json 2> $W/models/$k.eval.log; echo "$k evaluated rc=$? $(( $(date +%s)-T0 ))" ) &
done
wait
pack; rm -rf $OUT/res
echo "all done $(( $(date +%s)-T0 ))"
