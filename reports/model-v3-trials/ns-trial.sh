#!/usr/bin/env bash
# never-seen trial: fine-tune runs/models-v2/only-merl with ARGS, plausibility on rgl30
set -u
n=$1; shift
D=/work/runs/ft
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 BVAE_NUM_THREADS=1
cd /work/main && . /work/venv/bin/activate
bvae train runs/both.h5 -o $D/$n --init runs/models-v2/only-merl --quiet --train-families merl "$@" > $D/$n.log 2>&1 &&
bvae model export $D/$n -o $D/m-$n --name bvae-ft-$n --basis-count 0 --align-factors 300 --keep-axes >> $D/$n.log 2>&1 &&
bvae compress runs/rgl30.h5 --model $D/m-$n -o $D/m-$n-rgl30.bvae --no-measure >> $D/$n.log 2>&1 &&
bvae model plausibility $D/m-$n --library $D/m-$n-rgl30.bvae > $D/m-$n-plaus-rgl30.txt 2>> $D/$n.log
grep "^All" $D/m-$n-plaus-rgl30.txt
