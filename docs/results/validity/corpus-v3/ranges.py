"""Whole-finger curl range per clip and action on corpus v3's motion (issue 40): is there a gap for the gist's
20° threshold? 12 chunks of 64 one-segment sequences (seed 0), four fingers per hand, stable features.

    python docs/results/validity/corpus-v3/ranges.py > docs/results/validity/corpus-v3/ranges.txt   # ~10 s
"""
from collections import defaultdict

import numpy as np

from handx_jax.annotation import events as E
from handx_jax.annotation import descriptors as ft
from handx_jax.synthesis.bimanual import SynthConfig, synth_chunk

cfg = SynthConfig(motion="transition", segments_per_sequence=1)
R = defaultdict(list)
for ci in range(12):
    ch = synth_chunk(0, ci, cfg)
    flex = ft.compute_features(np.nan_to_num(ch.joints.astype(np.float64)), E.ANNOTATIONS["stable"].features).flexion_NxTx2x14
    curl = E.finger_curl_deg(flex)                                                    # (N, T, 2, 4)
    rng = np.ptp(curl, axis=1)                                                        # (N, 2, 4)
    for n, prog in enumerate(ch.programs):
        for h, side in enumerate(("left", "right")):
            R[prog[0][side]].extend(rng[n, h].tolist())
for a, v in sorted(R.items()):
    v = np.array(v)
    print(f"{a:14s} n={len(v):4d} p10/50/90 {np.percentile(v, 10):5.1f} {np.percentile(v, 50):5.1f} "
          f"{np.percentile(v, 90):5.1f}  share 15-40: {np.mean((v > 15) & (v < 40)):.2f}")
allv = np.concatenate([np.array(v) for v in R.values()])
print("hist by 10", np.histogram(allv, bins=np.arange(0, 101, 10))[0].tolist())
