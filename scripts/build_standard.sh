#!/usr/bin/env bash
# Rebuild the packaged standard evaluator from nothing (handx_jax/standard/, issue 13 item 1):
# the standard corpus -> SentencePiece tokenizer -> tiny T5 -> joined text cache -> evaluator -> package
# (copies the weights into handx_jax/assets/standard/, scores the Ground Truth rows at blocks 32 and 16 on the
# full test split, writes test_manifest.npz, card.json and CARD.md).
#
#   scripts/build_standard.sh [WORK]          (WORK default /tmp/handx-standard; keeps data/, t5/, evaluator/)
#
# Knobs (environment): STEPS BATCH LR WARMUP DROPOUT (evaluator; default v5's 2-core CPU recipe), PRESET (small),
# AUG_WHITE AUG_LOWFREQ (caption-preserving augmentation, mm; v5 1.5 and 3), MASK_SAME_TEXT REVERSE_NEGATIVE (v5
# true; v4 was STEPS=4500 with all four off), VALIDITY_CLIPS (4000: the prefix the validity suite runs on),
# ENCODER (a T5 encoder folder to reuse instead of training a tokenizer and a tiny T5; v4 reuses v3's, the
# packaged one: ENCODER=handx_jax/assets/standard/encoder), T5_STEPS (0 = the tiny preset's 2000), NICE (0),
# PY (python3), HARD_NEGATIVES (validity.perturb edits taken as negatives of a clip's own caption, comma-separated;
# default v8's swap_hands,swap_fingers; set it empty for v7 and before), CORPUS and STANDARD_VERSION (a named corpus version, standard.CORPUS_VERSIONS,
# and the version the card says, for the next evaluator before the code names it the standard one; default the
# code's recipe and standard.VERSION). scripts/build_standard_v8.sh is this with v8's knobs. The recipe itself
# (clip count, seed, generator version) is handx_jax.standard.Recipe: change it there and bump standard.VERSION,
# then run this. On a GPU, scripts/gpu_lease.sh does the same in one lease.
# Every stage resumes/skips when its output exists, so a killed run continues where it stopped.
set -euo pipefail
WORK=${1:-/tmp/handx-standard}
PY=${PY:-python3}
STEPS=${STEPS:-3000}
AUG_WHITE=${AUG_WHITE:-1.5}
AUG_LOWFREQ=${AUG_LOWFREQ:-3}
MASK_SAME_TEXT=${MASK_SAME_TEXT:-true}
REVERSE_NEGATIVE=${REVERSE_NEGATIVE:-true}
VALIDITY_CLIPS=${VALIDITY_CLIPS:-4000}
BATCH=${BATCH:-256}
LR=${LR:-1e-3}
WARMUP=${WARMUP:-300}
# No dropout on the 108k train clips of the 120k recipe (v4). v3's 17,918 clips needed 0.1 (it overfit without).
DROPOUT=${DROPOUT:-0.0}
PRESET=${PRESET:-small}
T5_STEPS=${T5_STEPS:-0}
HARD_NEGATIVES=${HARD_NEGATIVES-swap_hands,swap_fingers}  # unset: v8's; HARD_NEGATIVES= (empty): none, as v7
CORPUS=${CORPUS:-}
H=(nice -n "${NICE:-0}" "$PY" -m handx_jax)
mkdir -p "$WORK"
DATA=$WORK/data
t0=$(date +%s)
# The code's recipe (or CORPUS's), built with `data synth` (`standard corpus` refuses while the packaged card is the
# old recipe's)
read -r CLIPS FLAGS < <("$PY" -c "import sys; from handx_jax import standard as s
r = s.corpus_recipe(sys.argv[1]) if sys.argv[1] else s.code_recipe(); print(r.clips, r.synth_flags())" "$CORPUS")
# shellcheck disable=SC2086  # FLAGS is a list of flags
[ -f "$DATA/meta.json" ] || "${H[@]}" data synth --clips "$CLIPS" $FLAGS --out "$DATA" --quiet
t1=$(date +%s)
if [ -n "${ENCODER:-}" ]; then
  # package replaces the assets folder: keep a copy of a packaged encoder outside it
  [ -f "$WORK/t5/encoder/model.safetensors" ] || { mkdir -p "$WORK/t5" && cp -r "$ENCODER" "$WORK/t5/encoder"; }
else
  [ -f "$DATA/tokenizer/spiece.model" ] || "${H[@]}" text sentencepiece --data "$DATA"
  [ -f "$WORK/t5/encoder/model.safetensors" ] || \
    "${H[@]}" train t5 --data "$DATA" --preset tiny --out "$WORK/t5" --steps "$T5_STEPS" --log-every 200
fi
t2=$(date +%s)
if [ -n "${ENCODER:-}" ]; then ENCODER_NOTE="reused, copied from $ENCODER (its fingerprints above)"
else ENCODER_NOTE="SentencePiece tokenizer and tiny T5 trained on this corpus in $((t2 - t1)) s"; fi
[ -f "$WORK/evaluator/evaluator.json" ] || \
  "${H[@]}" train evaluator --data "$DATA" --encoder "$WORK/t5/encoder" --out "$WORK/evaluator" \
    --preset "$PRESET" --steps "$STEPS" --batch-size "$BATCH" --lr "$LR" --warmup "$WARMUP" --no-final-eval \
    --set train.optim.weight_decay=0.01 --set model.dropout="$DROPOUT" --set text.max_len=256 \
    --set data.text_bucket=256 --set train.log_every=100 --set train.ckpt_every=500 --set train.wandb=disabled \
    --set data.augment_white_mm="$AUG_WHITE" --set data.augment_lowfreq_mm="$AUG_LOWFREQ" \
    --set model.mask_same_text="$MASK_SAME_TEXT" --set model.reverse_negative="$REVERSE_NEGATIVE" \
    ${HARD_NEGATIVES:+--set model.hard_negatives="$HARD_NEGATIVES"}
t3=$(date +%s)
# Keep the packaged evaluator being replaced loadable by its name (--evaluator standard-vN) from a clone: it moves
# to evaluators/standard-vN/ (not installed; evaluators/README.md is the index: add its line).
OLD=$("$PY" -c "import json; from handx_jax import standard as s; print(json.loads((s.ASSETS / s.CARD_JSON).read_text())['version'])" 2>/dev/null || echo "")
NEW=${STANDARD_VERSION:-$("$PY" -c "from handx_jax import standard as s; print(s.VERSION)")}
ASSETS=$("$PY" -c "from handx_jax import standard as s; print(s.ASSETS)")
ARCHIVED=$("$PY" -c "from handx_jax import standard as s; print(s.ARCHIVE)")/standard-v$OLD
if [ -n "$OLD" ] && [ "$OLD" != "$NEW" ] && [ ! -d "$ARCHIVED" ]; then cp -r "$ASSETS" "$ARCHIVED"; fi
"${H[@]}" standard package --data "$DATA" --encoder "$WORK/t5/encoder" --evaluator "$WORK/evaluator" \
  --version "$NEW" ${CORPUS:+--corpus "$CORPUS"} \
  --note "corpus build=$((t1 - t0)) s wall on $(nproc) cores (handx data synth --clips $CLIPS $FLAGS)" \
  --note "evaluator training=$STEPS steps x $BATCH in $((t3 - t2)) s wall on $(nproc) cores, text cache included (scripts/build_standard.sh knobs: STEPS=$STEPS BATCH=$BATCH LR=$LR WARMUP=$WARMUP DROPOUT=$DROPOUT PRESET=$PRESET AUG_WHITE=$AUG_WHITE AUG_LOWFREQ=$AUG_LOWFREQ MASK_SAME_TEXT=$MASK_SAME_TEXT REVERSE_NEGATIVE=$REVERSE_NEGATIVE${HARD_NEGATIVES:+ HARD_NEGATIVES=$HARD_NEGATIVES}${CORPUS:+ CORPUS=$CORPUS STANDARD_VERSION=$NEW})" \
  --note "text encoder=$ENCODER_NOTE"
# The archived version keeps no copy of an encoder byte-identical to the new one (standard.asset_path reads the
# packaged one, still checked against the archived card's sha256).
if [ -d "$ARCHIVED/encoder" ] && diff -rq "$ARCHIVED/encoder" "$ASSETS/encoder" > /dev/null; then rm -r "$ARCHIVED/encoder"; fi
# The validity suite on a prefix with the packaged evaluator (a plain evaluator folder refuses a prefix of its
# corpus; the standard one accepts it), then its figures on the card.
PREFIX=$WORK/prefix$VALIDITY_CLIPS
[ -f "$PREFIX/meta.json" ] || "${H[@]}" standard corpus --clips "$VALIDITY_CLIPS" ${CORPUS:+--corpus "$CORPUS"} \
  --out "$PREFIX" --quiet
"${H[@]}" standard validity --data "$PREFIX" --out "$WORK/validity"
"${H[@]}" standard package --validity-only --validity "$WORK/validity/validity.json"
echo "done: $(( $(date +%s) - t0 )) s"
