#!/usr/bin/env bash
# Standard evaluator v8 (issue 55): v7's recipe (scripts/build_standard.sh's defaults) on standard corpus v5
# (handx data synth --annotation surface --motion surface: the hands resolved against the hand surface), with each
# clip's hand-swapped and finger-swapped motion as hard negatives of its own caption (model.hard_negatives;
# docs/results/validity/hard-negatives-small/ measures them at a small scale), and v7's packaged text encoder
# (v3's tokenizer and tiny T5, as v4-v7). Packages v8 into handx_jax/assets/standard/ (v7 moves to
# evaluators/standard-v7/), scores its Ground Truth rows, runs the validity suite on the 4,000-clip v5 prefix and
# puts its figures on the card.
#
#   scripts/build_standard_v8.sh [WORK]      (WORK default /tmp/handx-standard-v8; make standard-assets-v8)
#
# Every knob of build_standard.sh still applies (NICE, PY, STEPS ...). Then, to make v8 the code's standard
# evaluator, commit the assets with standard.VERSION = 8 and the standard recipe = corpus v5
# (handx_jax/standard/recipe.py: STANDARD_ANNOTATION = STANDARD_MOTION = "surface"), and add v7's line to
# evaluators/README.md.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
PY=${PY:-python3}
export CORPUS=v5 STANDARD_VERSION=8 HARD_NEGATIVES=${HARD_NEGATIVES:-swap_hands,swap_fingers}
export ENCODER=${ENCODER:-$("$PY" -c "from handx_jax import standard; print(standard.encoder_dir())")}
exec "$HERE/build_standard.sh" "${1:-/tmp/handx-standard-v8}"
