#!/usr/bin/env bash
# Re-runs docs/results/prediction/prefix4000: the data, the three runs, the scoring and the tables.
# Usage: run.sh WORK   (WORK: a scratch folder; the result files are written beside this script)
# Any other family's run is scored the same way: one more `handx eval prediction --run RUN --observed-frames 16
# --samples 20 --limit 76 [its own generation flags] --out $OUT/NAME.json` and NAME=$OUT/NAME.json in compare.py.
set -euo pipefail
W=$1; OUT=$(cd "$(dirname "$0")" && pwd); D=$W/D
ENC=$(python -c "from handx_jax import standard; print(standard.encoder_dir())")
export JAX_PLATFORMS=cpu
handx standard corpus --clips 4000 --out $D
handx text cache --data $D --encoder $ENC                      # per field (diffusion)
handx text cache --data $D --encoder $ENC --joined             # joined (AR)
handx train tokenizer --data $D --preset small --set train.steps=2000 --out $W/TOK
handx data tokens --tokenizer $W/TOK --data $D
DIFF="--preset tiny --set model.text_dim=64 --set train.batch_size=64 --set train.optim.lr=1e-3
      --set train.optim.schedule=cosine --set model.dropout=0.0"
# diffusion, observation-conditioned with the residual output, 200 steps (6.7e11 training FLOPs)
handx train diffusion --data $D --encoder $ENC $DIFF --set train.steps=200 --set train.optim.warmup_steps=50 \
    --set diffusion.observe_prob=1.0 --set diffusion.observe_residual=true --out $W/DIFF_RES
# AR LM at the same FLOPs (212 steps)
handx train ar --data $D --encoder $ENC --tokenizer $W/TOK --preset tiny --set train.steps=212 \
    --set train.optim.warmup_steps=50 --out $W/AR
# diffusion, observation-conditioned without the residual, 600 steps (3x the compute)
handx train diffusion --data $D --encoder $ENC $DIFF --set train.steps=600 --set train.optim.warmup_steps=100 \
    --set diffusion.observe_prob=0.8 --out $W/DIFF_OBS

P="--observed-frames 16 --samples 20 --limit 76"
for b in last-frame velocity ground-truth; do handx eval prediction --baseline $b --data $D $P --out $OUT/$b.json; done
handx eval prediction --run $W/DIFF_RES $P --sampler ddim --sample-steps 50 --out $OUT/diffusion_residual.json
handx eval prediction --run $W/DIFF_RES $P --sampler ddim --sample-steps 50 --guidance 1.0 \
    --out $OUT/diffusion_residual_cfg1.json
handx eval prediction --run $W/DIFF_OBS $P --sampler ddim --sample-steps 50 --out $OUT/diffusion_observe.json
handx eval prediction --run $W/AR $P --temperature 1.0 --out $OUT/ar.json
handx eval prediction --run $W/AR $P --out $OUT/ar_greedy.json
# G-HTT: the L2-d32 point (P + A, 1.8e12 FLOPs) of `handx sweep run sweeps/ghtt_cpu_study.py --preset cpu` on the
# same prefix (docs/results/ghtt); GHTT_RUN=SWEEP/runs/L2-d32-…
handx eval prediction --run ${GHTT_RUN:?the G-HTT run} $P --out $OUT/ghtt_L2-d32.json
python $OUT/tokenizer_oracle.py $W/TOK $D $OUT/tokenizer_oracle.json
python $OUT/compare.py "hold the last frame=$OUT/last-frame.json" "constant velocity=$OUT/velocity.json" \
    "diffusion, observe + residual, 200 steps (2.01e12 FLOPs)=$OUT/diffusion_residual.json" \
    "AR, T = 1, 212 steps (2.00e12 FLOPs)=$OUT/ar.json" "G-HTT L2-d32, P + A (1.8e12 FLOPs)=$OUT/ghtt_L2-d32.json" \
    "diffusion, observe, 600 steps (6.02e12 FLOPs)=$OUT/diffusion_observe.json" \
    "tokenizer oracle (perfect LM; reads the future)=$OUT/tokenizer_oracle.json" "the clip itself=$OUT/ground-truth.json"
