"""Finger-curl swing sizes on corpus v4's chain motion against corpus v3's transition (issue 40): is the gist's
20° threshold still in a gap, now that hands make up to three moves? 12 chunks of 64 one-segment sequences
(seed 0), four fingers per hand, stable features; swings found at 8° (segment.swings), sized end to end.

    python docs/results/validity/corpus-v4/swings.py > docs/results/validity/corpus-v4/swings.txt   # ~30 s
"""
import collections

import numpy as np

from handx_jax.annotation import events as E
from handx_jax.annotation import descriptors as ft
from handx_jax.annotation.segment import swings
from handx_jax.synthesis.bimanual import SynthConfig, synth_chunk

BINS = [8, 12, 16, 20, 24, 28, 32, 40, 60, 100]
for motion in ("transition", "chain"):
    cfg = SynthConfig(motion=motion, segments_per_sequence=1)
    amps, clips, then = [], 0, collections.Counter()
    for ci in range(12):
        ch = synth_chunk(0, ci, cfg)
        ok = np.isfinite(ch.joints).reshape(len(ch.joints), -1).all(1)
        flex = ft.compute_features(ch.joints[ok].astype(np.float64), E.ANNOTATIONS["stable"].features).flexion_NxTx2x14
        curl = E.finger_curl_deg(flex).transpose(0, 2, 3, 1).reshape(-1, flex.shape[1])   # (clips·hands·fingers, T)
        s, st, en, _ = swings(curl, 8.0)
        amps.append(np.abs(curl[s, en - 1] - curl[s, st]))
        clips += int(ok.sum())
        for p in ch.programs:
            for side in ("left", "right"):
                if p[0][side] != "idle":
                    then[len(p[0].get(f"{side}_then", "").split(", ")) if f"{side}_then" in p[0] else 0] += 1
    a = np.concatenate(amps)
    hist = np.histogram(a, bins=BINS)[0]
    print(f"{motion:10s} {clips} clips, {len(a) / clips:.1f} swings of >= 8 deg per clip; share 16-28 deg "
          f"{np.mean((a > 16) & (a < 28)):.3f}")
    print("  swing size bins", " ".join(f"{lo}-{hi}:{n}" for lo, hi, n in zip(BINS, BINS[1:], hist)))
    tot = sum(then.values())
    print("  acting hands by later moves", {k: round(v / tot, 3) for k, v in sorted(then.items())})
