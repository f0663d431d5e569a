"""Which descriptor limits the stable reading? (issue 40, diagnosis)

The perturbed clips are annotated with the stable reading, except that some descriptors are taken from
the CLEAN clips (smoothed as the reading smooths them): if a descriptor were perfectly robust, how many
level-0 captions would survive? Rows: none spliced, then flexion, + spacing, + intra-hand tip distances.

    python docs/results/validity/splice.py DATA OUT   # writes OUT/splice.json
"""
from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter1d

from handx_jax.annotation import events as E
from handx_jax.annotation import descriptors as ft
from handx_jax.annotation.caption import TemplateCaptioner
from handx_jax.dataset.format import Dataset
from handx_jax.validity import perturb as P
from handx_jax.validity import stability as S

SPLICES = ((), ("flexion_NxTx2x14",), ("flexion_NxTx2x14", "spacing_NxTx2x3"),
           ("flexion_NxTx2x14", "spacing_NxTx2x3", "intra_tip_NxTx2x4"))


def main(data: str, out: str) -> None:
    ds = Dataset.open(data)
    idx = ds.split("test")
    x = np.asarray(ds.motion[idx], np.float32)
    ids = [ds.ids[i] for i in idx]
    cfg = E.ANNOTATIONS["stable"]
    ann = S.Annotator(x, ids, 0, cfg, TemplateCaptioner("per_fact"))
    orig = ft.compute_features
    clean = orig(gaussian_filter1d(x.astype(np.float64), cfg.smooth_sigma_frames, axis=1, mode="nearest"), cfg.features)
    rows = []
    for kind, amp in (("white", 0.001), ("lowfreq", 0.003)):
        y = P.apply(kind, x, amp, 0)
        for keep in SPLICES:
            E.ft.compute_features = lambda j, c=None, keep=keep: dataclasses.replace(
                orig(j, c), **{k: getattr(clean, k) for k in keep})
            try:
                recs, caps = ann.records_and_captions(y)
            finally:
                E.ft.compute_features = orig
            r = S.compare(ann.clean_records, recs, ann.clean_captions, caps)
            per_field = [float(np.mean([a[0][f] == b[0][f] for a, b in zip(ann.clean_captions, caps)])) for f in range(3)]
            rows.append({"perturbation": f"{kind} {amp * 1000:g} mm", "clean descriptors": list(keep),
                         "events_unchanged": r["events_unchanged"], "level0_unchanged": r["captions_unchanged"][0],
                         "level0_unchanged_left_right_interaction": per_field})
            print(json.dumps(rows[-1]), flush=True)
    Path(out).mkdir(parents=True, exist_ok=True)
    (Path(out) / "splice.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
