"""The physics of a corpus's two hands, clip by clip (issue 55's targets): inter-hand penetration on the hand
surface, non-fingertip joints of the two hands too close, "apart" captions over overlapping surfaces, and touch
captions without surface contact in their stated frames. ``python -m handx_jax.synthesis.audit --data DIR``
prints the table docs/results/validity/corpus-v5/README.md gives; tests/test_synthesis_surface.py asserts it per clip.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from handx_jax import hand_surface as hs
from handx_jax import skeleton as sk
from handx_jax.annotation.caption.gist import palm_touch_frames

CONTACT_M = 0.005      # a touch: the surfaces within 5 mm (issue 55)
OVERLAP_M = -0.0005    # overlapping: more than 0.5 mm inside (the contact stage resolves to 0.2 mm)
APART = "The hands stay apart."
TOUCHES = ("The palms touch.", "The fingertips touch.", "The hands touch.")
_NON_TIP = np.array([j for j in range(sk.NUM_JOINTS) if j not in sk.TIPS])


def stated_frames(level0_interaction: str, relations: dict, T: int) -> np.ndarray:
    """(T,) bool: the frames a level-0 touch caption rests on (gist.interaction's reading of the record)."""
    m = np.zeros(T, bool)
    if level0_interaction == "The palms touch.":
        m = palm_touch_frames(relations, T)
    elif level0_interaction == "The fingertips touch.":
        for lst in relations.get("finger_tip_contact", {}).values():
            for e in lst:
                m[e["start"]:e["end"]] = True
    elif level0_interaction == "The hands touch.":
        for e in relations["surface_contact"]["left_hand, right_hand"]:
            m[e["start"]:e["end"]] = True
    return m


def audit(joints_NxTx2x21x3: np.ndarray, events: list[dict], level0_interaction: list[str]) -> dict[str, np.ndarray]:
    """Per clip: ``pen_1cm`` (share of frames with the surfaces > 1 cm inside each other), ``depth_mm`` (mean
    penetration depth), ``min_sd_mm``, ``nontip_mm`` (closest non-fingertip joints of the two hands over the
    clip), ``apart``/``touch`` (the level-0 interaction caption), ``apart_overlap`` (an "apart" clip with the
    surfaces overlapping on some frame) and ``touch_without_contact`` (a touch caption whose stated frames are
    empty or include a frame with the surfaces farther than 5 mm apart)."""
    x = np.asarray(joints_NxTx2x21x3, np.float32)
    N, T = x.shape[:2]
    sd = hs.in_batches(hs.interhand_signed_distance, x.reshape(N * T, 2, sk.NUM_JOINTS, 3)).reshape(N, T)
    a, b = x[:, :, sk.LEFT][:, :, _NON_TIP], x[:, :, sk.RIGHT][:, :, _NON_TIP]
    nontip = np.sqrt(((a[:, :, :, None] - b[:, :, None]) ** 2).sum(-1)).min((1, 2, 3))
    apart = np.array([t == APART for t in level0_interaction])
    touch = np.array([t in TOUCHES for t in level0_interaction])
    bad_touch = np.zeros(N, bool)
    for i in np.flatnonzero(touch):
        m = stated_frames(level0_interaction[i], events[i]["two_hand_relationships"], T)
        bad_touch[i] = (not m.any()) or bool((sd[i][m] > CONTACT_M + 1e-6).any())
    return {"pen_1cm": (sd < -0.01).mean(1), "depth_mm": 1000 * np.maximum(-sd, 0).mean(1), "min_sd_mm": 1000 * sd.min(1),
            "nontip_mm": 1000 * nontip, "apart": apart, "touch": touch,
            "apart_overlap": apart & (sd < OVERLAP_M).any(1), "touch_without_contact": touch & bad_touch}


def summary(a: dict[str, np.ndarray]) -> dict[str, float]:
    """The corpus-level figures of :func:`audit` (shares of clips unless named otherwise)."""
    n = len(a["pen_1cm"])
    return {"clips": n, "pen_1cm_pct": 100 * float(a["pen_1cm"].mean()), "depth_mm": float(a["depth_mm"].mean()),
            "deepest_mm": float(max(0.0, -a["min_sd_mm"].min())),
            "nontip_under_10mm": float((a["nontip_mm"] < 10).mean()), "nontip_under_5mm": float((a["nontip_mm"] < 5).mean()),
            "apart_clips": int(a["apart"].sum()), "apart_overlapping": int(a["apart_overlap"].sum()),
            "touch_clips": int(a["touch"].sum()), "touch_without_contact": int(a["touch_without_contact"].sum())}


def main(argv=None) -> int:
    from handx_jax.dataset.format import Dataset

    p = argparse.ArgumentParser(prog="python -m handx_jax.synthesis.audit", description=__doc__.split("\n")[0])
    p.add_argument("--data", required=True, help="dataset directory")
    p.add_argument("--split", default="test")
    p.add_argument("--json", help="write the summary here too")
    args = p.parse_args(argv)
    ds = Dataset.open(args.data)
    idx = ds.split(args.split)
    events = ds.events
    if events is None:
        print(f"{args.data}: no events.jsonl (the audit reads the annotation's contacts)", file=sys.stderr)
        return 2
    s = summary(audit(np.asarray(ds.motion[idx]), [events[i] for i in idx],
                      [ds.texts[i]["interaction"][0] for i in idx]))
    print(json.dumps(s, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(s, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
