#!/usr/bin/env bash
# One GPU lease for the autoregressive half (issue 30 item 7): Table 3 / Table 5 at the paper's LM sizes
# (8L-512, 12L-768, 16L-1024) x FSQ codebooks {512, 4096}, and the AR MFU, everything that must last packed
# under $OUT as soon as each part finishes.
#
#   OUT=DIR scripts/gpu_lease_ar.sh            (on the GPU machine, from the repository root)
#
# Stages (each skips or resumes what exists under WORK, so a command cut at its limit is finished by running
# the same command again on the still-warm machine):
#   data     the first CLIPS clips of the standard recipe (`handx standard corpus`: a prefix the packaged
#            standard evaluator scores) -> WORK/data
#   mfu      benchmarks/ar.py at the paper's tokenizer and LM sizes, bf16 -> $OUT/ar_mfu.json (BENCH=0 skips)
#   sweep    sweeps/ar_size_codebook.py --preset paper with codebooks CODEBOOKS, LM_STEPS and TOK_STEPS: one
#            tokenizer per codebook shared by the three LM sizes (the launcher's shared steps), every run
#            sampled and scored by the packaged standard evaluator. A packer loop writes
#            $OUT/ar_sweep.tar.gz (tables, logs, metrics; no checkpoints or samples) every PACK_EVERY seconds
#            and once more at the end, so a cut command still brings back every finished run.
#   tables   Table 3's layout, the top-3 vs FLOPs fit and LM size vs codebook factors -> $OUT/*.md, *.json, *.png
#
# Knobs (environment): CLIPS (6000) CODEBOOKS ([512,4096]) LM_STEPS (1000) TOK_STEPS (2000) LM_SET / TOK_SET
# (JSON lists of dotted overrides for every LM run / tokenizer step, e.g. '["train.batch_size=128"]')
# EVAL_LIMIT (512) EVAL_SAMPLES (2) MAX_PARALLEL (3) DEADLINE (seconds after start at which an unfinished
# sweep is stopped; its finished stages stay) BENCH (1) PACK_EVERY (30) PY WORK.
# A dry run on a CPU (minutes): CLIPS=600 CODEBOOKS=[256] LM_STEPS=20 TOK_STEPS=20 EVAL_LIMIT=32 \
#   SWEEP_PRESET=tiny BENCH=0 OUT=/tmp/lease-ar-out scripts/gpu_lease_ar.sh
# Measured as that dry run on the 2-core CPU (2026-11-27): 3 LM runs x 1 tokenizer, every row done and scored
# by standard v4, Table 3, the fit and a 16 KB ar_sweep.tar.gz back in 99 s after a first call (whose third run
# hit the RunLock race fixed in ad342cf) had built the corpus and the shared steps. Not yet run on a GPU.
set -uo pipefail
OUT=${OUT:?set OUT to the folder that comes back}
W=${WORK:-/tmp/lease_ar}
PY=${PY:-python3}
CLIPS=${CLIPS:-6000}
CODEBOOKS=${CODEBOOKS:-[512,4096]}
LM_STEPS=${LM_STEPS:-1000}
TOK_STEPS=${TOK_STEPS:-2000}
LM_SET=${LM_SET:-[]}
TOK_SET=${TOK_SET:-[]}
SWEEP_PRESET=${SWEEP_PRESET:-paper}
EVAL_LIMIT=${EVAL_LIMIT:-512}
EVAL_SAMPLES=${EVAL_SAMPLES:-2}
MAX_PARALLEL=${MAX_PARALLEL:-3}
DEADLINE=${DEADLINE:-540}
BENCH=${BENCH:-1}
PACK_EVERY=${PACK_EVERY:-30}
H=("$PY" -m handx_jax)
# Several JAX processes share one GPU: none may take 75% of its memory up front. The CPU malloc policy
# (handx_jax.infra.hostmem) is for XLA's CPU runtime; on a GPU machine glibc's defaults return memory.
export XLA_PYTHON_CLIENT_PREALLOCATE=false HANDX_HOST_MALLOC=system WANDB_MODE=disabled PYTHONUNBUFFERED=1
mkdir -p "$W" "$OUT"
t0=$(date +%s)
say() { echo "[$(( $(date +%s) - t0 )) s] $*" | tee -a "$OUT/lease.log"; }

say "start: $(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo no GPU)," \
    "$(nproc) cores; $("$PY" -c 'import sys, jax, numpy, flax; print(sys.version.split()[0], "jax", jax.__version__, "numpy", numpy.__version__, "flax", flax.__version__, jax.devices()[0].device_kind)')"
(nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv -l 5 > "$OUT/gpu_util.csv" 2>/dev/null &)

ENC=$("$PY" -c "from handx_jax import standard; print(standard.encoder_dir())")
EV=$("$PY" -c "from handx_jax import standard; print(standard.evaluator_dir())")

# data: a prefix of the standard recipe, so the packaged evaluator's test manifest holds for it
[ -f "$W/data/meta.json" ] || "${H[@]}" standard corpus --clips "$CLIPS" --out "$W/data" --quiet \
  >> "$OUT/lease.log" 2>&1 || { say "corpus failed"; exit 1; }
say "data: $CLIPS clips"

# mfu: the paper's sizes in bf16; a fresh child process per benchmark reports its own peak memory
if [ "$BENCH" = 1 ] && [ ! -f "$OUT/ar_mfu.json" ]; then
  timeout 240 "$PY" benchmarks/ar.py --tokenizer-presets paper --lm-presets 8L-512,12L-768,16L-1024 \
    --batch-size 128 > "$OUT/ar_mfu.json.tmp" 2>> "$OUT/lease.log" && mv "$OUT/ar_mfu.json.tmp" "$OUT/ar_mfu.json"
  say "mfu: exit $? ($(test -f "$OUT/ar_mfu.json" && echo written || echo missing))"
fi

pack() {
  [ -d "$W/sweep" ] || return 0
  "${H[@]}" sweep collect --out "$W/sweep" > /dev/null 2>&1
  tar czf "$OUT/ar_sweep.tar.gz.tmp" -C "$W" --exclude='checkpoints' --exclude='generated.npz' \
    --exclude='jax_cache' --exclude='*.msgpack' --exclude='*.npy' --exclude='.wandb-cache' sweep \
    && mv "$OUT/ar_sweep.tar.gz.tmp" "$OUT/ar_sweep.tar.gz"
}

# sweep: in the background, packed every PACK_EVERY seconds until it ends or DEADLINE passes
"${H[@]}" sweep run sweeps/ar_size_codebook.py --preset "$SWEEP_PRESET" --arg "codebooks=$CODEBOOKS" \
  --arg "steps=$LM_STEPS" --arg "tokenizer_steps=$TOK_STEPS" --arg "lm_set=$LM_SET" --arg "tokenizer_set=$TOK_SET" \
  --data "$W/data" --encoder "$ENC" --evaluator "$EV" --eval-limit "$EVAL_LIMIT" --eval-samples "$EVAL_SAMPLES" \
  --max-parallel "$MAX_PARALLEL" --out "$W/sweep" >> "$OUT/sweep.log" 2>&1 &
PS=$!
while kill -0 "$PS" 2>/dev/null && [ $(( $(date +%s) - t0 )) -lt "$DEADLINE" ]; do
  sleep "$PACK_EVERY"; pack
done
if kill -0 "$PS" 2>/dev/null; then
  say "sweep past $DEADLINE s: stopping it (finished stages stay; the same command resumes it)"
  pkill -TERM -P "$PS"; kill "$PS"; sleep 3
fi
wait "$PS"; say "sweep exit $?"; tail -n 20 "$OUT/sweep.log"
pack

# tables: whatever is scored so far (rows not scored yet are named and left out)
R="$W/sweep/results.csv"
if [ -f "$R" ]; then
  "${H[@]}" analyze table "$R" --layout table3 --out "$OUT/table3.md" >> "$OUT/lease.log" 2>&1
  "${H[@]}" analyze fit "$R" --x compute --y rprec_top3 --plot "$OUT/ar_fit.png" > "$OUT/ar_fit.txt" 2>&1
  "${H[@]}" analyze fit "$R" --x compute --y rprec_top3 --json > "$OUT/ar_fit.json" 2>> "$OUT/lease.log"
  "${H[@]}" analyze factors "$R" --factors params,codebook --json > "$OUT/ar_factors.json" 2>> "$OUT/lease.log"
  say "tables: $(ls "$OUT" | tr '\n' ' ')"
fi
say "done"
