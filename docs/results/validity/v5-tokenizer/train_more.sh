#!/usr/bin/env bash
# Issue 40 item 5: does the `small` tokenizer's v5 ratio move with more training, or with more tokens per second? Beside the AR CPU
# study's K1024 tokenizer (tiny preset at width 128 = `small`, 3,000 × 64):
#   down_t0: the same 3,000 steps without temporal downsampling (a code per frame: twice the rate)
#   steps6k: the same with 6,000 steps (twice the training; 9 min 30 s alone on 2 quiet cores)
# on the 4,000-clip corpus-v2 prefix, then decompose.py on them.
#   docs/results/validity/v5-tokenizer/train_more.sh DATA WORK
set -euo pipefail
DATA=${1:?dataset (the 4,000-clip corpus-v2 prefix)}
WORK=${2:?work folder}
PY=${PY:-.venv/bin/python}
export JAX_PLATFORMS=cpu WANDB_MODE=disabled XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
common=(train tokenizer --data "$DATA" --preset small --set model.codebook=1024 --set train.wandb=disabled --quiet)
[ -f "$WORK/steps6k/step_done" ] || { XLA_FLAGS= "$PY" -m handx_jax "${common[@]}" --set train.steps=6000 --out "$WORK/steps6k" &&
                                      touch "$WORK/steps6k/step_done"; }
[ -f "$WORK/down_t0/step_done" ] || { "$PY" -m handx_jax "${common[@]}" --set train.steps=3000 --set model.down_t=0 \
                                      --out "$WORK/down_t0" && touch "$WORK/down_t0/step_done"; }
