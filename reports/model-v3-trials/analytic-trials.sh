#!/usr/bin/env bash
set -u
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 BVAE_NUM_THREADS=1
cd /work/main && . /work/venv/bin/activate
for n in "$@"; do
  M=/work/runs/ft/m-$n
  bvae compress runs/analytic30.h5 --model $M -o $M-analytic30.bvae --no-measure --force > /dev/null 2>&1
  bvae model plausibility $M --library $M-analytic30.bvae > $M-plaus-analytic30.txt 2>/dev/null
  echo "$n $(grep '^All' $M-plaus-analytic30.txt)"
done
