"""Physics and BimArt metrics of a hand–object corpus (issue 52), for docs/results/objects/README.md.

    JAX_PLATFORMS=cpu .venv/bin/python docs/results/objects/measure.py DATASET [--out metrics.json]

Per clip, with metrics/objects.py (BimArt §4): the ground truth; the hands of another clip (the next clip of the
same category) on this clip's object trajectory; and the hands held still at their first frame. Physics
figures (issue 52 item 3) come from synthesis/object_physics.py on the stored files.
"""

import argparse
import json
import sys

import numpy as np

from handx_jax.dataset.format import Dataset
from handx_jax.metrics import objects as M
from handx_jax.objects import surface_samples
from handx_jax.synthesis import object_physics as phys
from handx_jax.synthesis.object_build import clip_object, open_object_annotations
from handx_jax.synthesis.object_motion import stack_objects


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("data")
    ap.add_argument("--out")
    ap.add_argument("--clips", type=int, default=None, help="at most this many clips")
    a = ap.parse_args(argv)
    ds = Dataset.open(a.data)
    ann = open_object_annotations(a.data)
    n = len(ds) if a.clips is None else min(a.clips, len(ds))
    joints = np.asarray(ds.motion[:n], np.float64)
    states = np.asarray(ann["object_state"][:n], np.float64)
    recs = ann["objects"][:n]
    cats = [r["category"] for r in recs]
    other = []
    for i, c in enumerate(cats):   # the next clip of the same category (cyclically)
        same = [j for j in range(n) if cats[j] == c and j != i]
        other.append(next((j for j in same if j > i), same[0] if same else i))
    variants = {"ground truth": joints, "another clip's hands": joints[other],
                "hands still at frame 0": np.repeat(joints[:, :1], joints.shape[1], 1)}
    objs = [clip_object(r) for r in recs]
    samples = [np.stack([np.asarray(surface_samples(o, p, 512, 0)[0]) for p in (0, 1)]) for o in objs]
    gt_contacts = None
    table = {}
    gt_maps = None
    for name, J in variants.items():
        rows = []
        contacts = []
        for i in range(n):
            pts = M.hand_points_from_joints(J[i])
            near = M.hand_part_distances(objs[i], states[i], pts)
            m = M.obj_penetration(near)
            m["obj_con"] = M.obj_contact(near, M.moving_frames(objs[i], states[i], samples[i]))
            m["obj_art"] = M.obj_articulation(near, M.articulating_frames(states[i]))
            m.update(M.obj_accel(pts))
            c = M.part_contacts(near)
            contacts.append(c)
            if gt_contacts is not None:
                m.update(M.obj_part_contact_f1(c, gt_contacts[i]))
            rows.append(m)
        if gt_contacts is None:
            gt_contacts = contacts
        maps = phys.contact_maps(stack_objects(objs), np.asarray(ann["bps_points"][:n]), states, J)
        if gt_maps is None:
            gt_maps = maps
        summary = {k: float(np.nanmean([r[k] for r in rows])) for k in rows[0]}
        summary["obj_cm_l1_m"] = M.obj_cm_l1(np.clip(maps, 0, 0.1), np.clip(gt_maps, 0, 0.1))
        table[name] = summary
        print(name, json.dumps({k: round(v, 5) for k, v in summary.items()}), file=sys.stderr)
    out = {"clips": n, "metrics": table, "note": "contact maps clipped at 10 cm before the CM L1"}
    if a.out:
        with open(a.out, "w") as f:
            json.dump(out, f, indent=1)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
