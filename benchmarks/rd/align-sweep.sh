#!/usr/bin/env bash
# Issue 41 on the device: traversal penalty in any direction, weights W, each for all 120 (release candidate)
# and the 3 CV folds; export aligned to the analytic factors; plausibility of the release candidates;
# the chosen recipe's 4 models come back (without their basis, which is refitted here).
# On the device: bash benchmarks/rd/align-sweep.sh with the two NBRDF zips in .gpu/ and the wheels of
# colour-science and zstandard in .whl/ (carried). Local dry run:
# DRY=1 DATASET=runs/both.h5 OUT=/tmp/out EPOCHS=1 WEIGHTS=10 bash benchmarks/rd/align-sweep.sh
set -u
T0=$(date +%s); el() { echo $(( $(date +%s) - T0 )); }
W=${WORK:-/tmp/align}; mkdir -p "$W/runs" "$W/models" "$OUT"
if [ -z "${DRY:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 3
  export PYTHONPATH=/tmp/site:$PWD
  nvidia-smi -L
fi
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 BVAE_NUM_THREADS=1
B="python3 -m brdfcodec"
EPOCHS=${EPOCHS:-150}; TL=${TL:-230}
WEIGHTS=${WEIGHTS:-"10 30 100"}
DATASET=${DATASET:-$W/both.h5}
if [ ! -f "$DATASET" ]; then
  OMP_NUM_THREADS=16 $B dataset build --nbrdf-zip .gpu/merl-nbrdf-90.zip --nbrdf-zip .gpu/rgl-nbrdf-30.zip -o "$DATASET" > "$W/dataset.log" 2>&1 || { cat "$W/dataset.log"; exit 4; }
fi
echo "$(el)s dataset ready"
R="--model small --epochs $EPOCHS --weight-decay 1 --mix-probability 0.9 --keep last --quiet --time-limit $TL --traversal-directions any"
for w in $WEIGHTS; do
  $B train "$DATASET" -o "$W/runs/all-w$w" $R --traversal-weight $w --all-materials > "$W/runs/all-w$w.log" 2>&1 &
  for f in 0 1 2; do
    $B train "$DATASET" -o "$W/runs/f$f-w$w" $R --traversal-weight $w --folds 3 --fold $f > "$W/runs/f$f-w$w.log" 2>&1 &
  done
done
wait
echo "$(el)s trained"
for r in "$W"/runs/*/; do n=$(basename "$r"); [ -f "$r/best.pt" ] || continue
  $B model export "$r" -o "$W/models/$n" --name "bvae-any-$n" --basis-count 0 --align-factors 300 > "$W/models/$n.log" 2>&1 &
done
wait
echo "$(el)s exported"
for w in $WEIGHTS; do n=all-w$w; [ -f "$W/models/$n/model.json" ] || continue
  ( $B compress "$DATASET" --model "$W/models/$n" -o "$W/models/$n-lib.bvae" --no-measure > "$W/models/$n-compress.log" 2>&1 &&
    timeout 150 $B model plausibility "$W/models/$n" --library "$W/models/$n-lib.bvae" --json > "$W/models/$n-plausibility.json" 2> "$W/models/$n-plausibility.err" ) &
done
wait
echo "$(el)s plausibility"
python3 - "$W" > "$OUT/runs.jsonl" <<'PY'
import json, sys, pathlib
w = pathlib.Path(sys.argv[1])
for run in sorted((w / "runs").glob("*/")):
    rows = [json.loads(l) for l in (run / "log.jsonl").read_text().splitlines() if l.strip()] if (run / "log.jsonl").exists() else []
    evals = [r for r in rows if "val_relae_mapped" in r]
    summ = json.loads((run / "summary.json").read_text()) if (run / "summary.json").exists() else {}
    print(json.dumps({"run": run.name, "summary": summ, "last": rows[-1] if rows else {}, "last_eval": evals[-1] if evals else None}))
PY
# the recipe: lowest mean CV held-out error among weights whose release candidate has ≤ 3 % implausible
# decodes (any kind) and none unphysical; else the most plausible
python3 - "$W" "$OUT" "$WEIGHTS" > "$W/pick.txt" <<'PY'
import json, sys, pathlib
w, out, weights = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2]), sys.argv[3].split()
runs = {json.loads(l)["run"]: json.loads(l) for l in (out / "runs.jsonl").read_text().splitlines()}
def mean(xs): return sum(xs) / len(xs) if xs else float("inf")
rows = []
for x in weights:
    held = [((runs.get(f"f{f}-w{x}") or {}).get("last_eval") or {}).get("val_relae_mapped", float("inf")) for f in range(3)]
    try:
        p = json.loads((w / "models" / f"all-w{x}-plausibility.json").read_text())["fractions"]
        frac = {k: mean([v for row in p[k] for v in row]) for k in p}
    except Exception:
        frac = {"any": 1.0, "unphysical": 1.0}
    rows.append({"weight": x, "heldout": mean(held), "any": frac["any"], "unphysical": frac["unphysical"], **{f"frac_{k}": v for k, v in frac.items()}})
(out / "pick.json").write_text(json.dumps(rows, indent=1))
ok = [r for r in rows if r["any"] <= 0.03 and r["unphysical"] == 0]
best = min(ok, key=lambda r: r["heldout"]) if ok else min(rows, key=lambda r: r["any"])
print(best["weight"])
PY
X=$(cat "$W/pick.txt"); echo "picked weight $X"; cat "$OUT/pick.json"
for n in all-w$X f0-w$X f1-w$X f2-w$X; do
  [ -d "$W/models/$n" ] && tar -C "$W" -cf "$OUT/$n.tar" "models/$n" "runs/$n/run.json" "runs/$n/log.jsonl" "runs/$n/summary.json"
done
if [ $(el) -lt 480 ]; then
  timeout $(( 540 - $(el) )) $B model disentanglement $(ls -d "$W"/models/all-w*/) --materials 300 --seed 0 -o "$W/disentanglement.jsonl" > "$W/disentanglement.txt" 2>&1
  echo "$(el)s disentanglement rc $?"
fi
tar -C "$W" -czf "$OUT/results.tgz" $(cd "$W" && ls runs/*.log models/*.log models/*-plausibility.* models/*-compress.log models/*/model.json disentanglement.* 2>/dev/null)
ls -la "$OUT"; echo "$(el)s done"
