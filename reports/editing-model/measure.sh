#!/usr/bin/env bash
# The editing model's export, encoder refit and measurements (reports/editing-model/editing-model.txt), from the
# repository root, once `bvae train` (the command in the model card's Training section) has written
# runs/s27/edit-release.
# Data: bvae dataset build --nbrdf-zip ../shared/data/merl-nbrdf-90.zip --nbrdf-zip ../shared/data/rgl-nbrdf-30.zip
#   -o runs/both.h5; the same with --rgl ../shared/data/rgl --random 24 -o runs/v3-held-out.h5; and
#   bvae dataset build --random 24 -o runs/random24.h5. Then:
#   python reports/editing-model/editing_model_rows.py --card packages/brdfcodec-editing-model/brdfcodec_editing_model/models/editing
# (after copying runs/models/s28-edit-v1-refit to that folder). Run here as two or three chains side by side, one per
# core. Session 27 exported and measured the model as trained (runs/models/s27-edit-v1, runs/s27/eval); session 28
# refitted its encoder (the refit's command, in model.json's info.encoder_refit, started from the packaged folder,
# which was runs/models/s27-edit-v1 byte for byte) and measured again what depends on the encoder, into
# runs/s28/release-eval, beside the default model's measurements copied from runs/s27/eval.
set -euo pipefail
EXPORTED=runs/models/s27-edit-v1
M=runs/models/s28-edit-v1-refit
E=runs/s28/release-eval
DEFAULT=brdfcodec/data/models/default
mkdir -p "$E"
export BRDFCODEC_MODEL_PATH=$PWD/$M   # the libraries compressed with it name its decoder
bvae model export runs/s27/edit-release -o "$EXPORTED" --name bvae-nbrdf-proxy-edit-v1 --dataset runs/both.h5 \
  --align-factors 300 --keep-axes --command "$(cat runs/s27/cmd-edit-release.txt)"
bvae model compact-encoder "$EXPORTED"
bvae model refit-encoder "$EXPORTED" --dataset runs/both.h5 -o "$M" --analytic-batch 8
bvae model disentanglement "$M" "$DEFAULT" --materials 300 --seed 0 -o "$E/dis-seed0.jsonl" --force
bvae model disentanglement "$M" "$DEFAULT" --materials 300 --seed 2 --no-pca -o "$E/dis-seed2.jsonl" --force
for effort in 0 1; do
  suffix=$([ "$effort" = 1 ] && echo "e1-" || echo "")
  bvae model evaluate "$M" --dataset runs/v3-held-out.h5 --effort "$effort" --json > "$E/evaluate-${suffix}s28-edit-v1-refit.json"
  bvae model evaluate "$DEFAULT" --dataset runs/v3-held-out.h5 --effort "$effort" --json > "$E/evaluate-${suffix}default.json"
done
bvae compress runs/both.h5 -o runs/s28/lib-edit.bvae --model "$M" --no-measure --force
bvae compress runs/both.h5 -o runs/s27/lib-v3.bvae --no-measure --force
bvae compress runs/random24.h5 -o runs/s28/lib-edit-analytic.bvae --model "$M" --no-measure --force
bvae compress runs/random24.h5 -o runs/s27/lib-v3-analytic.bvae --no-measure --force
for name in gold-metallic-paint blue-acrylic; do
  bvae render runs/s28/lib-edit.bvae --material "$name" --traversal -o "reports/traversals/editing-model-$name.png" --force
done
bvae model plausibility "$M" --library runs/s28/lib-edit.bvae --materials 40 --highlight-guard --json > "$E/plaus-edit-guard.json"
bvae model plausibility "$M" --library runs/s28/lib-edit.bvae --materials 40 --json > "$E/plaus-edit-raw.json"
bvae model plausibility --library runs/s27/lib-v3.bvae --materials 40 --highlight-guard --json > "$E/plaus-v3-guard.json"
bvae model plausibility --library runs/s27/lib-v3.bvae --materials 40 --json > "$E/plaus-v3-raw.json"
bvae model plausibility "$M" --library runs/s28/lib-edit-analytic.bvae --highlight-guard --json \
  > "$E/plaus-edit-guard-analytic.json"
bvae model plausibility --library runs/s27/lib-v3-analytic.bvae --highlight-guard --json > "$E/plaus-v3-guard-analytic.json"
