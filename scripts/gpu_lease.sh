#!/usr/bin/env bash
# One GPU lease (issue 13): the standard evaluator rebuilt on a GPU, and the Fig. 4 ladder, side by side on one
# accelerator, everything that must last packed under $OUT.
#
#   OUT=DIR scripts/gpu_lease.sh            (on the GPU machine, from the repository root)
#
# Two branches run at once (the GPU is shared; the CPU cores are split between them):
#   evaluator  the standard corpus (handx_jax.standard.Recipe: change the recipe there and bump VERSION first)
#              -> joined text cache -> small evaluator, EV_STEPS x EV_BATCH -> `handx standard package` (test
#              manifest, card, GT rows at blocks 32 and 16) -> $OUT/standard_assets.tar
#   ladder     the first LADDER_CLIPS clips of the recipe (a prefix; 6,000 = 5% of a 120k corpus) -> text
#              cache -> sweeps/diffusion_flops_ladder.py (LADDER_PRESET, all seven sizes at once), scored by
#              the packaged evaluator while the new one trains -> $OUT/ladder.tar.gz as soon as it is done
# then: a copy of the code takes the new assets (the checkout is never changed), the ladder is rescored by them
# (same samples), and the sweep's tables, logs and metrics (no checkpoints, no samples) go to $OUT/ladder.tar.gz.
#
# Every stage skips or resumes what exists under WORK (corpus, text caches, the evaluator's checkpoints every
# 1,000 steps, the sweep's runs), so a command cut at its limit is finished by running the same command again
# on the still-warm machine (it keeps /tmp for 30 s after a call). Measured on one H200 (2026-11-26, both
# branches together): 120k-clip corpus 313 s (synthesis 176 s of it), joined cache of 600k captions 149 s,
# evaluator ~19k samples/s (8,000 x 256: ~110 s), the short ladder 516 s. The joined cache now holds level 0
# only (`--levels 0`, a fifth of the captions), so the evaluator branch alone should take ~450 s: run it with
# LADDER=0 first, and again at once if it was cut.
#
# Knobs (environment): EVALUATOR=0|1 LADDER=0|1 CLIPS (default: the code's recipe) LADDER_CLIPS EV_STEPS
# EV_BATCH EV_LR EV_WARMUP LADDER_PRESET LADDER_STEPS LADDER_ARGS SAMPLER_STEPS EVAL_SAMPLES SYNTH_WORKERS
# DEADLINE (seconds after start at which an unfinished ladder is stopped) RESCORE_END, RECIPE_CLIPS (dry runs:
# package against a prefix), PY, WORK. A dry run on a CPU: CLIPS=1500 LADDER_CLIPS=600 EV_STEPS=20
# LADDER_PRESET=tiny LADDER_STEPS=4 SAMPLER_STEPS=4 RECIPE_CLIPS=1500 OUT=/tmp/lease-out scripts/gpu_lease.sh
set -uo pipefail
OUT=${OUT:?set OUT to the folder that comes back}
W=${WORK:-/tmp/lease}
PY=${PY:-python3}
case "$PY" in */*) PY="$(cd "$(dirname "$PY")" && pwd)/$(basename "$PY")";; esac  # the rescore runs elsewhere
CLIPS=${CLIPS:-$("$PY" -c "from handx_jax.standard import code_recipe; print(code_recipe().clips)")}
EVALUATOR=${EVALUATOR:-1}
LADDER=${LADDER:-1}
LADDER_CLIPS=${LADDER_CLIPS:-6000}
EV_STEPS=${EV_STEPS:-8000}
EV_BATCH=${EV_BATCH:-256}
EV_LR=${EV_LR:-1e-3}
EV_WARMUP=${EV_WARMUP:-500}
LADDER_PRESET=${LADDER_PRESET:-short}
LADDER_STEPS=${LADDER_STEPS:-1000}
SAMPLER_STEPS=${SAMPLER_STEPS:-50}
EVAL_SAMPLES=${EVAL_SAMPLES:-4}
SYNTH_WORKERS=${SYNTH_WORKERS:-13}
DEADLINE=${DEADLINE:-500}
RESCORE_END=${RESCORE_END:-575}
ENC=handx_jax/assets/standard/encoder
H=("$PY" -m handx_jax)
# Several JAX processes share one GPU: none may take 75% of its memory up front. The CPU malloc policy
# (handx_jax.infra.hostmem) is for XLA's CPU runtime; on a GPU machine glibc's defaults return memory.
export XLA_PYTHON_CLIENT_PREALLOCATE=false HANDX_HOST_MALLOC=system WANDB_MODE=disabled PYTHONUNBUFFERED=1
mkdir -p "$W" "$OUT"
t0=$(date +%s)
say() { echo "[$(( $(date +%s) - t0 )) s] $*"; }

say "start: $(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo no GPU)," \
    "$(nproc) cores; $("$PY" -c 'import sys, jax, numpy, flax; print(sys.version.split()[0], "jax", jax.__version__, "numpy", numpy.__version__, "flax", flax.__version__, jax.devices()[0].device_kind)')"
(nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv -l 5 > "$W/gpu_util.csv" 2>/dev/null &)

# stage NAME CMD...: run CMD and add its wall seconds to WORK/NAME.seconds (summed over resumed calls, so the
# card's timings are the whole stage's, not the last call's share).
stage() {
  local name=$1 a; shift; a=$(date +%s)
  "$@"
  echo $(( $(cat "$W/$name.seconds" 2>/dev/null || echo 0) + $(date +%s) - a )) > "$W/$name.seconds"
  say "$name: $(cat "$W/$name.seconds") s"
}
secs() { cat "$W/$1.seconds" 2>/dev/null || echo "?"; }

# The code's standard recipe as `data synth` flags (handx_jax.standard.Recipe: reading and motion; `standard corpus`
# refuses while the packaged card is an older recipe's, which is the case this script exists for).
RECIPE_FLAGS=$("$PY" -c "from handx_jax.standard import code_recipe as r; print(r().synth_flags())")

evaluator_branch() {
  set -e
  [ -f "$W/std/meta.json" ] || \
    stage corpus "${H[@]}" data synth --clips "$CLIPS" $RECIPE_FLAGS --out "$W/std" --workers "$SYNTH_WORKERS" --quiet
  # Level 0 only: the evaluator trains and scores there (the full cache, all five levels, took 149 s).
  stage joined_cache "${H[@]}" text cache --data "$W/std" --encoder "$ENC" --joined --levels 0 --max-len 256 \
    --batch-size 1024
  [ -f "$W/evaluator/evaluator.json" ] || \
    stage evaluator_training "${H[@]}" train evaluator --data "$W/std" --encoder "$ENC" --out "$W/evaluator" \
      --preset small --steps "$EV_STEPS" --batch-size "$EV_BATCH" --lr "$EV_LR" --warmup "$EV_WARMUP" \
      --train-levels 0 --no-final-eval --set train.optim.weight_decay=0.01 --set train.prefetch=8 \
      --set text.max_len=256 --set data.text_bucket=256 --set train.log_every=200 --set train.ckpt_every=1000 \
      --set train.wandb=disabled --set data.augment_white_mm=1.5 --set data.augment_lowfreq_mm=3 \
      --set model.mask_same_text=true --set model.reverse_negative=true
  local dev
  dev=$("$PY" -c 'import jax; print(jax.devices()[0].device_kind)')
  [ -f "$W/assets/card.json" ] || \
    stage package "${H[@]}" standard package --data "$W/std" --encoder "$ENC" --evaluator "$W/evaluator" \
      --out "$W/assets" ${RECIPE_CLIPS:+--recipe-clips "$RECIPE_CLIPS"} \
      --note "machine=one $dev, $(nproc) CPU cores (scripts/gpu_lease.sh; LADDER=$LADDER: the GPU $( [ "$LADDER" = 1 ] && echo shared with || echo without) the Fig. 4 ladder)" \
      --note "corpus build=$(secs corpus) s wall ($SYNTH_WORKERS synthesis workers)" \
      --note "joined text cache=$(secs joined_cache) s wall (level 0, max_len 256)" \
      --note "evaluator training=$(secs evaluator_training) s wall, compilation (and any resumption) included" \
      --note "command=scripts/gpu_lease.sh (EV_STEPS=$EV_STEPS EV_BATCH=$EV_BATCH EV_LR=$EV_LR EV_WARMUP=$EV_WARMUP, train levels 0, no dropout, weight decay 0.01)" \
      --note "status=trained on a GPU; the text encoder and tokenizer are v3's, unchanged"
  tar cf "$OUT/standard_assets.tar" -C "$W/assets" .
  tar cf "$OUT/evaluator_run.tar" -C "$W/evaluator" config.json metrics.jsonl evaluator.json
}

ladder_branch() {
  set -e
  local ev3
  ev3=$("$PY" -c "from handx_jax import standard; print(standard.evaluator_dir())")
  [ -f "$W/ladder_data/meta.json" ] || \
    stage ladder_corpus "${H[@]}" data synth --clips "$LADDER_CLIPS" $RECIPE_FLAGS --out "$W/ladder_data" --workers 4 --quiet
  stage ladder_cache "${H[@]}" text cache --data "$W/ladder_data" --encoder "$ENC" --batch-size 512
  HANDX_CACHE_DIR="$W/cache_old" "${H[@]}" sweep run sweeps/diffusion_flops_ladder.py --preset "$LADDER_PRESET" \
    --arg fraction=1.0 --arg steps="$LADDER_STEPS" ${LADDER_ARGS:-} --data "$W/ladder_data" --encoder "$ENC" \
    --evaluator "$ev3" --eval-limit 100000 --eval-samples "$EVAL_SAMPLES" --set "sample.steps=$SAMPLER_STEPS" \
    --max-parallel 7 --out "$W/ladder"
  say "ladder: trained, sampled, scored by the packaged evaluator"
  pack_ladder
}

pack_ladder() {
  tar czf "$OUT/ladder.tar.gz.tmp" -C "$W" --exclude='checkpoints' --exclude='generated.npz' --exclude='jax_cache' \
    --exclude='*.msgpack' --exclude='.wandb-cache' ladder && mv "$OUT/ladder.tar.gz.tmp" "$OUT/ladder.tar.gz"
}

# The branch logs are written straight into $OUT: they come back even if the command is killed at its limit.
# stop_after PID SECONDS NAME: wait for a branch until SECONDS after the start, then stop it; its exit code in RC.
stop_after() {
  while kill -0 "$1" 2>/dev/null && [ $(( $(date +%s) - t0 )) -lt "$2" ]; do sleep 2; done
  if kill -0 "$1" 2>/dev/null; then
    say "$3 past $2 s: stopping it (its finished stages stay; the same command resumes it)"
    pkill -TERM -P "$1"; kill "$1"; sleep 3
  fi
  wait "$1"
  RC=$?
}
rc_ev=skipped; rc_l=skipped
if [ "$EVALUATOR" = 1 ]; then evaluator_branch >> "$OUT/evaluator.log" 2>&1 & PE=$!; fi
if [ "$LADDER" = 1 ]; then ladder_branch >> "$OUT/ladder.log" 2>&1 & PL=$!; fi
if [ "$EVALUATOR" = 1 ]; then
  stop_after "$PE" "$RESCORE_END" evaluator; rc_ev=$RC
  say "evaluator branch exit $rc_ev"; tail -n 25 "$OUT/evaluator.log"
fi
if [ "$LADDER" = 1 ]; then
  stop_after "$PL" "$DEADLINE" ladder; rc_l=$RC
  say "ladder branch exit $rc_l"; tail -n 30 "$OUT/ladder.log"
fi

if [ -f "$W/assets/card.json" ] && [ -d "$W/ladder" ]; then
  # A copy of the code takes the new assets (the checkout is left as it is), so the rescore goes through the
  # standard path (card, manifest check of the prefix) exactly as a user's `--evaluator standard` will.
  rm -rf "$W/tree" && mkdir -p "$W/tree" && cp -r handx_jax sweeps analysis "$W/tree/" && \
    rm -rf "$W/tree/handx_jax/assets/standard" && cp -r "$W/assets" "$W/tree/handx_jax/assets/standard"
  left=$(( RESCORE_END - ($(date +%s) - t0) )); [ "$left" -lt 20 ] && left=20
  (cd "$W/tree" && HANDX_CACHE_DIR="$W/cache_new" PYTHONPATH="$W/tree" timeout "$left" "$PY" -m handx_jax sweep \
    rescore "$W/ladder" --evaluator "$W/tree/handx_jax/assets/standard/evaluator" --max-parallel 7) \
    > "$W/rescore.log" 2>&1
  say "rescore exit $?"; tail -n 12 "$W/rescore.log"
fi
[ -d "$W/ladder" ] && "${H[@]}" sweep collect --out "$W/ladder" > /dev/null 2>&1
mkdir -p "$W/lease_logs" && cp "$W"/*.log "$W/gpu_util.csv" "$W/lease_logs/" 2>/dev/null
[ -d "$W/evaluator" ] && cp "$W/evaluator/metrics.jsonl" "$W/lease_logs/evaluator_metrics.jsonl" 2>/dev/null
tar czf "$OUT/logs.tar.gz" -C "$W" lease_logs
[ -d "$W/ladder" ] && pack_ladder
say "done"; ls -la "$OUT"
