#!/usr/bin/env bash
# Build the built-in 20k corpus, then train the paper-preset evaluator on one accelerator with the number
# of steps chosen to fill a wall-clock budget, and print the Ground Truth rows (issue #4's acceptance run).
#
#   scripts/train_evaluator_gpu.sh OUT ENCODER [TRAIN_SECONDS]
#
# OUT receives the evaluator folder, its log and gt_rows.jsonl. A 60-step probe run measures samples/s
# (after compilation) so that the real run's cosine schedule is sized to the budget up front; the step
# count it picked is in the log and in OUT/evaluator/config.json. Extra settings go in EVAL_SET
# (space-separated key=value pairs for --set), e.g. EVAL_SET="text.eval_level=-1". Text is padded to one shape
# (text_bucket = MAX_LEN): on an accelerator every new text length would recompile the whole step.
# TRAIN_LEVELS (default all) and WARMUP (default 300) pass through; MAX_STEPS caps the probe's step count
# (more epochs than the corpus supports only overfits it).
# PACK=DIR also writes the evaluator's files (no checkpoints) as DIR/evaluator.tar.NN pieces of 15 MB.
set -euo pipefail
OUT=${1:?usage: $0 OUT ENCODER [TRAIN_SECONDS]}
ENC=${2:?usage: $0 OUT ENCODER [TRAIN_SECONDS]}
BUDGET=${3:-270}
DATA=${DATA:-/tmp/handx-c20k}
CLIPS=${CLIPS:-20000}
PRESET=${PRESET:-paper}
BATCH=${BATCH:-256}
LR=${LR:-2e-4}
MAX_LEN=${MAX_LEN:-384}
PY=${PYTHON:-python3}
TRAIN_LEVELS=${TRAIN_LEVELS:-all}
WARMUP=${WARMUP:-300}
SETS=(--set "text.max_len=$MAX_LEN" --set "data.text_bucket=$MAX_LEN")
for kv in ${EVAL_SET:-}; do SETS+=(--set "$kv"); done
mkdir -p "$OUT"
t0=$(date +%s)
[ -f "$DATA/meta.json" ] || $PY -m handx_jax data synth --clips "$CLIPS" --seed 0 --out "$DATA" --workers 0 --quiet
echo "corpus: $(( $(date +%s) - t0 )) s, fingerprint $($PY -c "import json;print(json.load(open('$DATA/meta.json'))['fingerprint'])")"

$PY -m handx_jax text cache --data "$DATA" --encoder "$ENC" --joined --max-len "$MAX_LEN" --batch-size 1024
echo "text cache: $(( $(date +%s) - t0 )) s"
if [ -n "${STEPS:-}" ]; then
  echo "steps given: $STEPS (no probe)"
else
rm -rf /tmp/handx-probe
$PY -m handx_jax train evaluator --data "$DATA" --encoder "$ENC" --out /tmp/handx-probe --preset "$PRESET" \
  --steps 40 --batch-size "$BATCH" --lr "$LR" --train-levels "$TRAIN_LEVELS" --no-final-eval "${SETS[@]}" \
  --set train.log_every=20 --set train.ckpt_every=100000 --set train.wandb=disabled
RATE=$($PY -c "import json;r=[json.loads(l) for l in open('/tmp/handx-probe/metrics.jsonl')];print(r[-1]['samples_per_s'])")
STEPS=$($PY -c "print(min(${MAX_STEPS:-10**9}, max(200, int($RATE * $BUDGET / $BATCH))))")
echo "probe: $RATE samples/s -> $STEPS steps of batch $BATCH for ${BUDGET} s (setup so far $(( $(date +%s) - t0 )) s)"
fi

$PY -m handx_jax train evaluator --data "$DATA" --encoder "$ENC" --out "$OUT/evaluator" --preset "$PRESET" \
  --steps "$STEPS" --batch-size "$BATCH" --lr "$LR" --warmup "$WARMUP" --train-levels "$TRAIN_LEVELS" "${SETS[@]}" \
  --set train.log_every=200 --set train.ckpt_every=100000 --set train.wandb=disabled
echo "trained: $(( $(date +%s) - t0 )) s"
if [ -n "${PACK:-}" ]; then
  mkdir -p "$PACK"
  (cd "$OUT/evaluator" && tar cf - evaluator.json params.msgpack norm_stats.npz eval.json config.json metrics.jsonl) \
    | split -b 15M -d - "$PACK/evaluator.tar."
fi

# The Ground Truth row at every caption level, blocks of 32 (Table 2) and 16 (Fig. 4): one process.
$PY - "$OUT/evaluator" "$DATA" "${GT_ROWS:-$OUT/gt_rows.jsonl}" ${GT_LEVELS:-} <<'PYEOF'
import dataclasses, json, sys
from handx_jax.dataset.format import Dataset
from handx_jax.evaluation import evaluate_ground_truth, load_evaluator
from handx_jax.metrics import MetricConfig
ev = load_evaluator(sys.argv[1]); ds = Dataset.open(sys.argv[2])
levels = int(ds.meta["levels"])
with open(sys.argv[3], "w") as f:
    for level in [int(x) for x in sys.argv[4].split(",")] if len(sys.argv) > 4 else range(levels):
        ev.policy = dataclasses.replace(ev.policy, eval_level=level)
        for block in (32, 16):
            res = evaluate_ground_truth(ev, ds, MetricConfig(rprec_block=block))
            row = {"level": level, "block": block, **res.flat()}
            f.write(json.dumps(row) + "\n"); f.flush()
            print(f"level {level} block {block}: top1 {row['rprec_top1']:.3f} top2 {row['rprec_top2']:.3f} "
                  f"top3 {row['rprec_top3']:.3f} mm {row['mm_dist']:.3f} div {row['diversity']:.3f}", flush=True)
PYEOF
echo "done: $(( $(date +%s) - t0 )) s"
