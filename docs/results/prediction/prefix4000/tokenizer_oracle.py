"""A measurement, not a predictor: what the AR family would score with a perfect LM (README, "What limits AR").

The clip's own 30 codes (the whole clip encoded, so the future is read: an oracle) are decoded by the tokenizer
and joined to the observed frames exactly as the AR family's prediction is (families.ar.stitch); scored like
`handx eval prediction` (K = 1, no evaluator). The gap between this row and holding the last frame is what the
tokenizer allows; the gap between it and the AR run is the LM's.

    python docs/results/prediction/prefix4000/tokenizer_oracle.py TOK DATA OUT.json [LIMIT] [STITCH] [SPLIT]
"""

import json
import sys

import numpy as np

from handx_jax.dataset.format import Dataset
from handx_jax.evaluation import prediction as PR
from handx_jax.families import tokenizer as T
from handx_jax.families.ar import stitch
from handx_jax.families.ar.decode import tokens_to_joints
from handx_jax.generation import split_prompts

tok_dir, data, out = sys.argv[1:4]
limit = int(sys.argv[4]) if len(sys.argv) > 4 else 76
frames = int(sys.argv[5]) if len(sys.argv) > 5 else -1  # the AR family's default
N = 16
tok = T.load(tok_dir)
split = sys.argv[6] if len(sys.argv) > 6 else "test"
clips, _, sources = split_prompts(Dataset.open(data), split, limit, -1)
src = np.stack(sources)
codes = tok.encode_clips(src)  # (clips, 30)
dec = tokens_to_joints(tok.model, tok.params, codes, np.full(len(codes), codes.shape[1]), tok.norm)
pred = stitch(dec, src, N, frames)
res = PR.score(pred[None], src, N, PR.horizon_bins(N))
res["_meta"] = {"oracle": "the clip's own codes through the tokenizer, stitched", "tokenizer": tok_dir,
                "clips": len(clips), "observed_frames": N, "stitch_frames": frames, "ci": PR.CI}
with open(out, "w") as f:
    json.dump(res, f, indent=1)
print(PR.format_table(res))
