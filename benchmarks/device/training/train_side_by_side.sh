#!/bin/bash
# One device session's training: several `bvae train` runs side by side on one GPU, sized by a short probe to end
# by a deadline, scored there (MIG, DCI on the disentanglement benchmark; mapped RelAE per family), their weights
# brought back under $OUT in chunks the device tool returns (benchmarks/device/README.md, "Training").
#
# Env:
#   OUT       folder whose files come back (the device tool's $OUT)
#   COMMIT    the checkout's commit (.git does not travel)
#   CONFIGS   runs, one "NAME ARGUMENTS" line each (default: from-scratch-supervision.configs beside this script)
#   COMMON    arguments of every run (default: the release recipe's, below)
#   DATA      folder holding merl-nbrdf-90.zip and rgl-nbrdf-30.zip (default .devrun/data, carried)
#   WHEELS    folder of wheels to install first, if it exists (default .devrun/whl, carried)
#   DEADLINE  seconds after the start by which everything has ended (default 560; the device tool's limit is 600)
#   BENCH_S   seconds given to device_benchmark.py beside the runs' start (default 60; 0: none)
#   BENCH_STAGES  its stages (default environment,throughput,cross-device)
#   BENCH_ARGS    more of its arguments (e.g. --llvm-reference reports/device/llvm-reference/renders.npz)
#   SCORE_SOURCES dataset sources scored beside the training ones but never trained on (e.g. "--random 24 --rgl
#                 .devrun/data/rgl"): the runs are scored on a second dataset of both (default: none)
#   MARGIN    the runs' seconds per epoch over the probe's (default 1.5: four runs side by side took 0.65-0.72 s
#             an epoch where their probe had measured 0.39-0.52 s)
#   QUICK=1   a rehearsal on the CPU: 10 MERL-family materials, 3 epochs, a 16-material pool
set -u
T0=$(date +%s)
el() { echo $(( $(date +%s) - T0 )); }
log() { echo "[$(el)s] $*"; }
HERE=$(cd "$(dirname "$0")" && pwd)
CONFIGS=${CONFIGS:-$HERE/from-scratch-supervision.configs}
COMMON=${COMMON:-"--all-materials --keep last --mix-probability 0.9 --weight-decay 1.0 --traversal-weight 300 --traversal-hole-margin 0.05 --traversal-directions axes --quiet"}
DATA=${DATA:-.devrun/data}
WHEELS=${WHEELS:-.devrun/whl}
DEADLINE=${DEADLINE:-560}
BENCH_S=${BENCH_S:-60}
BENCH_STAGES=${BENCH_STAGES:-environment,throughput,cross-device}
BENCH_ARGS=${BENCH_ARGS:-}
SCORE_SOURCES=${SCORE_SOURCES:-}
MARGIN=${MARGIN:-1.5}
QUICK=${QUICK:-0}
W=${WORK:-/tmp/devwork}; rm -rf "$W"; mkdir -p "$W/runs" "$W/logs"
if [ -d "$WHEELS" ] && [ "$QUICK" != 1 ]; then
  python3 -m pip install -q --upgrade --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site "$WHEELS"/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
export PYTHONUNBUFFERED=1 BRDFCODEC_COMMIT=${COMMIT:-unknown}
command -v nvidia-smi > /dev/null && nvidia-smi -L | head -2
echo "cores $(nproc)"
python3 -c "import torch, numpy; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'numpy', numpy.__version__)"
declare -A EXTRA=()
while read -r name rest; do
  case "$name" in ''|'#'*) continue ;; esac
  EXTRA[$name]="$rest"
done < "$CONFIGS"
RUNS=("${!EXTRA[@]}")
echo "runs: ${RUNS[*]}"

# 1. the dataset (both shared NBRDF archives) and the disentanglement benchmark's 300 materials, on the CPU
log "dataset build"
if [ "$QUICK" = 1 ]; then
  SOURCES="--nbrdf-zip $DATA/merl-nbrdf-90.zip --materials neoprene-rubber,green-acrylic,red-fabric,green-fabric,white-fabric,blue-rubber,ss440,chrome,yellow-phenolic,pure-rubber"
else
  SOURCES="--nbrdf-zip $DATA/merl-nbrdf-90.zip --nbrdf-zip $DATA/rgl-nbrdf-30.zip"
fi
python3 -m brdfcodec dataset build $SOURCES -o "$W/both.h5" --jobs "$(nproc)" --quiet > "$W/logs/dataset.log" 2>&1 &
DS=$!
SCORED=$W/both.h5
if [ -n "$SCORE_SOURCES" ]; then
  SCORED=$W/scored.h5
  python3 -m brdfcodec dataset build $SOURCES $SCORE_SOURCES -o "$SCORED" --jobs "$(nproc)" --quiet > "$W/logs/scored-dataset.log" 2>&1 &
  SDS=$!
fi
python3 "$HERE/score_runs.py" --bench-only "$W/bench.npz" > "$W/logs/bench.log" 2>&1 &
BENCH=$!
wait $DS || { log "dataset build failed"; cat "$W/logs/dataset.log"; exit 1; }
log "dataset built"
POOL=512; [ "$QUICK" = 1 ] && POOL=16

# 2. probe: every run side by side for 3 epochs (a 16-material pool), to size the real runs
log "probe"
PIDS=()
for r in "${RUNS[@]}"; do
  python3 -m brdfcodec train "$W/both.h5" -o "$W/probe-$r" $COMMON ${EXTRA[$r]} --factor-materials 16 --epochs 3 --time-limit 90 > "$W/logs/probe-$r.log" 2>&1 &
  PIDS+=($!)
done
for p in "${PIDS[@]}"; do wait $p; done
log "probe done"
START=$(el)
TRAIN_END=$(( DEADLINE - 75 ))
PLAN=$(python3 - "$W" "$START" "$TRAIN_END" "$POOL" "$QUICK" "$MARGIN" "${RUNS[@]}" <<'EOF'
import json, sys
work, start, end, pool, quick, margin, *runs = sys.argv[1:]
start, end, pool, margin = int(start), int(end), int(pool), float(margin)
for run in runs:
    try:  # seconds per epoch: the mean of epochs 2 and 3 (the first holds the warm-up)
        records = [json.loads(line) for line in open(f"{work}/probe-{run}/log.jsonl") if line.strip()]
        per_epoch = max(sum(r["seconds"] for r in records[1:]) / max(1, len(records[1:])), 0.05)
        supervised = any(r.get("factor", 0) for r in records)
    except (OSError, ValueError, KeyError):
        per_epoch, supervised = 5.0, True
    tabulate = pool * 0.07 if supervised else 0  # the factor pool, tabulated before the first epoch
    epochs = 3 if quick == "1" else max(3, int((end - start - tabulate - 15) / (per_epoch * margin)))
    print(run, epochs, max(30, end - start), round(per_epoch, 3))
EOF
)
echo "$PLAN" | tee "$W/logs/plan.txt"

# 3. the real runs, side by side; the device benchmark beside their pool tabulation
PIDS=()
for r in "${RUNS[@]}"; do
  E=$(echo "$PLAN" | awk -v r="$r" '$1==r {print $2}'); TL=$(echo "$PLAN" | awk -v r="$r" '$1==r {print $3}')
  python3 -m brdfcodec train "$W/both.h5" -o "$W/runs/$r" $COMMON ${EXTRA[$r]} --factor-materials $POOL --epochs "$E" --time-limit "$TL" > "$W/logs/train-$r.log" 2>&1 &
  PIDS+=($!)
done
log "runs started"
if [ "$BENCH_S" != 0 ]; then
  if [ "$QUICK" = 1 ]; then DB="--device cpu --quick --budget-s $BENCH_S"; else DB="--device cuda --budget-s $BENCH_S"; fi
  python3 benchmarks/device/device_benchmark.py --out "$W/logs/devbench" $DB --stages "$BENCH_STAGES" $BENCH_ARGS > "$W/logs/devbench.log" 2>&1
  log "device benchmark done"
fi
wait $BENCH
for p in "${PIDS[@]}"; do wait $p; done
log "runs done"
for r in "${RUNS[@]}"; do tail -c 300 "$W/logs/train-$r.log"; cat "$W/runs/$r/summary.json" 2>/dev/null; echo; done

# 4. scores on the device, one process per run; slim weights for the trip back
log "score"
if [ -n "$SCORE_SOURCES" ]; then wait $SDS || { log "scored dataset build failed"; cat "$W/logs/scored-dataset.log"; SCORED=$W/both.h5; }; fi
PIDS=()
for r in "${RUNS[@]}"; do
  python3 "$HERE/score_runs.py" "$SCORED" "$W/bench.npz" "$W/logs/eval-$r.jsonl" "$W/runs/$r" > "$W/logs/eval-$r.log" 2>&1 &
  PIDS+=($!)
done
for p in "${PIDS[@]}"; do wait $p; done
cat "$W"/logs/eval-*.jsonl > "$W/logs/eval.jsonl"; cat "$W/logs/eval.jsonl"
log "scored"

# 5. pack: the logs in one archive; the slim weights (most disentangled first, then the unsupervised) in chunks
for r in "${RUNS[@]}"; do mkdir -p "$W/logs/runs/$r"; cp "$W/runs/$r"/{log.jsonl,run.json,summary.json} "$W/logs/runs/$r/" 2>/dev/null; done
tar czf "$OUT/logs.tar.gz" -C "$W" logs
python3 - "$W" "$OUT" <<'EOF'
import io, json, os, sys, tarfile
work, out = sys.argv[1:]
rows = [json.loads(line) for line in open(f"{work}/logs/eval.jsonl") if line.strip()]
done = [r for r in rows if "error" not in r and os.path.exists(f"{work}/runs/{r['run']}/slim.pt")]
done.sort(key=lambda r: -(r["mig"] + r["dci_d"]))
chosen, total = [], 0
for row in done:  # the device tool returns at most 64 MB: a run that does not fit stays behind
    size = os.path.getsize(f"{work}/runs/{row['run']}/slim.pt")
    if total + size <= 63_000_000:
        chosen.append(row["run"])
        total += size
buffer = io.BytesIO()
with tarfile.open(fileobj=buffer, mode="w") as tar:
    for run in chosen:
        tar.add(f"{work}/runs/{run}/slim.pt", arcname=f"{run}/slim.pt")
data = buffer.getvalue()
for i in range(0, len(data), 15_000_000):
    with open(f"{out}/models.tar.{i // 15_000_000}", "wb") as chunk:
        chunk.write(data[i:i + 15_000_000])
print("packed", chosen, len(data), "left behind", [r["run"] for r in done if r["run"] not in chosen])
EOF
ls -la "$OUT"
log "end"
