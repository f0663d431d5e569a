#!/usr/bin/env bash
# Corpus v3 (120k, gist + transition) and a candidate evaluator on it, v5 recipe (3,000 steps x 256).
# Usage: docs/results/validity/corpus-v3/build_and_train.sh [WORK]   (2 CPU cores: corpus 785 s, evaluator 2,487 s).
# Every stage skips when its output exists. The committed evaluator-candidate/ is this script's evaluator.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
W=${1:-/tmp/handx-corpus-v3}
H=(.venv/bin/python -m handx_jax)
t0=$(date +%s)
[ -f $W/data/meta.json ] || "${H[@]}" data synth --clips 120000 --seed 0 --annotation gist --motion transition --out $W/data --workers 2 --quiet
t1=$(date +%s); echo "corpus $((t1-t0)) s"
[ -f $W/t5/encoder/model.safetensors ] || { mkdir -p $W/t5 && cp -r handx_jax/assets/standard/encoder $W/t5/encoder; }
[ -f $W/evaluator/evaluator.json ] || "${H[@]}" train evaluator --data $W/data --encoder $W/t5/encoder --out $W/evaluator \
    --preset small --steps ${STEPS:-3000} --batch-size 256 --lr 1e-3 --warmup 300 --no-final-eval \
    --set train.optim.weight_decay=0.01 --set model.dropout=0.0 --set text.max_len=256 \
    --set data.text_bucket=256 --set train.log_every=100 --set train.ckpt_every=500 --set train.wandb=disabled \
    --set data.augment_white_mm=1.5 --set data.augment_lowfreq_mm=3 \
    --set model.mask_same_text=true --set model.reverse_negative=true
t2=$(date +%s); echo "evaluator $((t2-t1)) s"
