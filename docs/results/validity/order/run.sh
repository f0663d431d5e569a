#!/usr/bin/env bash
# Issue 40: does training on reversed clips with their own captions teach the standard evaluator the order of
# events? A small test on the 4,000-clip prefix of corpus v2 (the validity suite's clips): standard evaluator v5
# fine-tuned on the prefix's train split, with and without its reversed copy mixed into the batches, then the
# validity suite on the prefix's 230 test clips (disjoint from the train split) for each.
#   [ARMS="reversed pairs control"] docs/results/validity/order/run.sh WORK [STEPS]
set -euo pipefail
WORK=${1:?work folder}
STEPS=${2:-300}
PY=${PY:-.venv/bin/python}
H=("$PY" -m handx_jax)
export JAX_PLATFORMS=cpu WANDB_MODE=disabled
ENC=$("$PY" -c "from handx_jax import standard; print(standard.encoder_dir())")
EV=$("$PY" -c "from handx_jax import standard; print(standard.evaluator_dir())")
mkdir -p "$WORK"
[ -f "$WORK/data/meta.json" ] || "${H[@]}" standard corpus --clips 4000 --out "$WORK/data" --quiet
[ -f "$WORK/rev/meta.json" ] || "${H[@]}" data reverse --data "$WORK/data" --out "$WORK/rev" --workers 1
common=(--data "$WORK/data" --encoder "$ENC" --preset small --steps "$STEPS" --batch-size 128 --lr 2e-4 --warmup 30
        --no-final-eval --set "init_from=$EV" --set train.optim.weight_decay=0.01 --set text.max_len=256
        --set data.text_bucket=256 --set train.log_every=50 --set train.ckpt_every=100 --set train.wandb=disabled
        --set data.augment_white_mm=1.5 --set data.augment_lowfreq_mm=3 --set model.mask_same_text=true
        --set model.reverse_negative=true)
for arm in ${ARMS:-reversed pairs control}; do
  extra=()
  [ "$arm" = reversed ] && extra=(--set "data.reversed_path=$WORK/rev" --set data.reversed_share=0.3)
  # pairs: half of each batch is the reversals of the other half (a clip and its own reversal meet)
  [ "$arm" = pairs ] && extra=(--set "data.reversed_path=$WORK/rev" --set data.reversed_share=0.5 --set data.reversed_pairs=true)
  [ -f "$WORK/E-$arm-$STEPS/evaluator.json" ] || "${H[@]}" train evaluator "${common[@]}" "${extra[@]}" --out "$WORK/E-$arm-$STEPS"
  [ -f "$WORK/val-$arm-$STEPS/validity.json" ] || "${H[@]}" standard validity --data "$WORK/data" --evaluator "$WORK/E-$arm-$STEPS" \
      --kinds white,lowfreq,reverse,other --out "$WORK/val-$arm-$STEPS"
done
