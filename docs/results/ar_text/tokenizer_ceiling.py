"""Tokenizer ceiling: test clips -> FSQ codes -> decoded joints, written as a generated .npz (level-0 prompts)."""
import sys, numpy as np, jax.numpy as jnp
from handx_jax.families import tokenizer as T
from handx_jax.families.ar import decode as AD
from handx_jax.dataset.format import Dataset
from handx_jax.generation import split_prompts, write_generated
tok = T.load(sys.argv[1]); ds = Dataset.open(sys.argv[2])
clips, prompts, motion = split_prompts(ds, "test", None, 0)
codes = np.asarray(tok.encode_clips(np.stack(motion)))
j = AD.tokens_to_joints(tok.model, tok.params, codes, np.full(len(codes), codes.shape[1]), tok.norm)
print(codes.shape, j.shape, "mpjpe-ish mm", float(np.linalg.norm(j - j[:, :1, 1:2] - (np.stack(motion) - np.stack(motion)[:, :1, 1:2]), axis=-1).mean() * 1000))
write_generated(sys.argv[3], j, [[p] for p in prompts], source_clips=[ds.ids[c] for c in clips], groups=[0]*len(clips))
