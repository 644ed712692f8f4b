#!/bin/bash
# GPU sweep 1 (issue 12): dataset build, 8 runs in parallel, export + evaluate. Writes to $OUT.
# Run from the repository root on the GPU machine; .devdata/ (git-ignored) held merl-nbrdf-90.zip, rgl-nbrdf-30.zip
# and whl/ (zstandard, OpenEXR and colour-science wheels for Python 3.12, which that machine lacked).
set -u
T0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .devdata/whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.used --format=csv
W=/tmp/w; mkdir -p $W/runs $W/models $OUT/res
echo "build start $(( $(date +%s)-T0 ))"
python3 -m brdfcodec dataset build --nbrdf-zip .devdata/merl-nbrdf-90.zip --nbrdf-zip .devdata/rgl-nbrdf-30.zip -o $W/both.h5 > $OUT/res/build.log 2>&1 || { cat $OUT/res/build.log; exit 1; }
echo "build done $(( $(date +%s)-T0 ))"
R="--model small --mix-probability 0.9 --traversal-weight 10 --weight-decay 1.0 --quiet"
TL=${TL:-270}
declare -A CFG
CFG[r300]="$R"
CFG[r300s1]="$R --seed 1"
CFG[r900]="$R --epochs 900 --eval-every 30"
CFG[b32e1200]="$R --batch-size 32 --lr 6e-4 --epochs 1200 --eval-every 40"
CFG[mix05]="$R --mix-probability 0.5"
CFG[perm1]="$R --permute-colours 1.0"
CFG[trav30]="${R/--traversal-weight 10/--traversal-weight 30}"
CFG[z12]="$R --latent-dim 12"
for k in "${!CFG[@]}"; do
  OMP_NUM_THREADS=2 python3 -m brdfcodec train $W/both.h5 -o $W/runs/$k ${CFG[$k]} --time-limit $TL > $W/runs/$k.log 2>&1 &
done
wait
echo "train done $(( $(date +%s)-T0 ))"
for k in "${!CFG[@]}"; do cp $W/runs/$k/log.jsonl $OUT/res/$k-log.jsonl 2>/dev/null; done; (cd $OUT && tar czf res.tgz res)
for k in "${!CFG[@]}"; do
  ( OMP_NUM_THREADS=2 timeout 150 python3 -m brdfcodec model export $W/runs/$k -o $W/models/$k --name bvae-gpu-$k-trial --basis-count 0 > $W/models/$k.export.log 2>&1 &&
    OMP_NUM_THREADS=2 timeout $(( 540 - ($(date +%s)-T0) )) python3 -m brdfcodec model evaluate $W/models/$k --dataset $W/both.h5 --json > $OUT/res/$k-e0.json 2> $W/models/$k.eval.log ) &
done
wait
echo "eval done $(( $(date +%s)-T0 ))"
for k in "${!CFG[@]}"; do cp $W/runs/$k/log.jsonl $OUT/res/$k-log.jsonl 2>/dev/null; cp $W/runs/$k/run.json $OUT/res/$k-run.json 2>/dev/null; tail -3 $W/runs/$k.log $W/models/$k.export.log $W/models/$k.eval.log 2>/dev/null; done
cd $OUT && tar czf res.tgz res && rm -rf res
echo "all done $(( $(date +%s)-T0 ))"
