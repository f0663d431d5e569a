#!/usr/bin/env bash
# Rebuild the packaged standard evaluator from nothing (handx_jax/standard.py, issue 13 item 1):
# the standard corpus -> SentencePiece tokenizer -> tiny T5 -> joined text cache -> evaluator -> package
# (copies the weights into handx_jax/assets/standard/, scores the Ground Truth rows at blocks 32 and 16 on the
# full test split, writes test_manifest.npz, card.json and CARD.md).
#
#   scripts/build_standard.sh [WORK]          (WORK default /tmp/handx-standard; keeps data/, t5/, evaluator/)
#
# Knobs (environment): STEPS BATCH LR WARMUP DROPOUT (evaluator; default v3's 2-core CPU recipe), PRESET (small),
# T5_STEPS (0 = the tiny preset's 2000), NICE (0), PY (python3). The recipe itself (clip count, seed,
# generator version) is handx_jax.standard.Recipe: change it there and bump standard.VERSION, then run this.
# Every stage resumes/skips when its output exists, so a killed run continues where it stopped.
set -euo pipefail
WORK=${1:-/tmp/handx-standard}
PY=${PY:-python3}
STEPS=${STEPS:-3000}
BATCH=${BATCH:-128}
LR=${LR:-1e-3}
WARMUP=${WARMUP:-100}
# Dropout 0.1: without it the small evaluator overfits the 17,918 training pairs (v3's card).
DROPOUT=${DROPOUT:-0.1}
PRESET=${PRESET:-small}
T5_STEPS=${T5_STEPS:-0}
H=(nice -n "${NICE:-0}" "$PY" -m handx_jax)
mkdir -p "$WORK"
DATA=$WORK/data
t0=$(date +%s)
[ -f "$DATA/meta.json" ] || "${H[@]}" standard corpus --out "$DATA" --quiet
t1=$(date +%s)
[ -f "$DATA/tokenizer/spiece.model" ] || "${H[@]}" text tokenizer --data "$DATA"
[ -f "$WORK/t5/encoder/model.safetensors" ] || \
  "${H[@]}" text pretrain --data "$DATA" --preset tiny --out "$WORK/t5" --steps "$T5_STEPS" --log-every 200
t2=$(date +%s)
[ -f "$WORK/evaluator/evaluator.json" ] || \
  "${H[@]}" eval train-evaluator --data "$DATA" --encoder "$WORK/t5/encoder" --out "$WORK/evaluator" \
    --preset "$PRESET" --steps "$STEPS" --batch-size "$BATCH" --lr "$LR" --warmup "$WARMUP" --no-final-eval \
    --set train.optim.weight_decay=0.01 --set model.dropout="$DROPOUT" --set train.log_every=100 --set train.ckpt_every=200 --set train.wandb=disabled
t3=$(date +%s)
"${H[@]}" standard package --data "$DATA" --encoder "$WORK/t5/encoder" --evaluator "$WORK/evaluator" \
  --note "corpus build=$((t1 - t0)) s" --note "tokenizer + tiny T5=$((t2 - t1)) s" \
  --note "text cache + evaluator training=$((t3 - t2)) s" \
  --note "command=STEPS=$STEPS BATCH=$BATCH LR=$LR WARMUP=$WARMUP DROPOUT=$DROPOUT PRESET=$PRESET scripts/build_standard.sh"
echo "done: $(( $(date +%s) - t0 )) s"
