"""Collapse check of generated files: distinct motions among the prompts' first samples; mean distance between
different prompts' samples vs between one prompt's samples (metres, joints flattened)."""
import sys, json, numpy as np
from handx_jax.interop.handx_npz import read_handx_npz
out = {}
for f in sys.argv[1:]:
    cl = read_handx_npz(f)
    g = np.array([c.group if c.group is not None else 0 for c in cl])
    m = np.stack([c.motion for c in cl]).reshape(len(cl), -1)
    G = int(g.max()) + 1
    x = m.reshape(-1, G, m.shape[-1])  # (prompts, groups, D): entries are clip-major
    first = x[:, 0]
    between = np.linalg.norm(first[:, None] - first[None], axis=-1)
    within = np.mean([np.linalg.norm(x[:, a] - x[:, b], axis=-1).mean() for a in range(G) for b in range(a + 1, G)]) if G > 1 else 0.0
    out[f] = dict(prompts=len(x), groups=G, distinct_first=int(len(np.unique(first.round(4), axis=0))),
                  between_prompts=round(float(between.sum() / (len(x) * (len(x) - 1))), 3), within_prompt=round(float(within), 3))
    print(f, out[f])
