"""BimArt App. E, Tab. III on the procedural corpus: the contact-map error due to the BPS mapping, per part.

    .venv/bin/python docs/results/bimart/bps_mapping.py --data DIR --k 64 --out docs/results/bimart/bps_mapping.json

For every clip of a hand-object corpus (``handx data objects``) and three mappings of the same feature width 2K:

- U-BPS: 2K basis points uniform in a 0.5 m ball, the object unnormalised, mapped to the whole object (Fig. 4 left);
- PA-BPS: 2K points in the unit ball, the object scaled by s_o (Eq. 1), mapped to the whole object (part-agnostic);
- P-BPS: K points in the unit ball mapped to each part separately (Eq. 2, what the models use);

the dense ground-truth contact map (each of 2048 area-uniform samples per part: its distance to the nearest hand,
clipped at 0.2 m, the paper's contact range) is compared, L1 per sample in cm, with the map interpolated from the
mapped points only (each dense sample takes its nearest mapped point's value: the paper interpolates with the
Vector Heat method, a smoother interpolant on a mesh). Beside it, the mapping's coverage: the mean distance (mm)
from a dense sample to its nearest mapped point of the same part. Mapping is at the canonical angle (0); the
contact values are each frame's. Hands: the corpus's own motion.
"""

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import hand_surface as hs
from handx_jax.dataset.format import Dataset
from handx_jax.objects import BOTTOM, TOP, surface_samples
from handx_jax.objects.bps import DEFAULT_SCALE_ANGLE, SCALE_ANGLE, basis_points, map_basis, object_scale
from handx_jax.objects.features import mapped_points_world
from handx_jax.synthesis.object_build import clip_object, open_object_annotations

CLIP_M = 0.2
N_DENSE = 2048


@jax.jit
def _dense_contact(dense_2xNx3, states_Tx7, joints_Tx2x21x3):
    """(T, 2 parts, N): distance of each dense sample to the nearer hand, clipped at CLIP_M."""
    world = mapped_points_world(dense_2xNx3, states_Tx7)                              # (T, 2, N, 3)
    T = world.shape[0]
    pts = jnp.broadcast_to(world.reshape(T, 1, -1, 3), (T, 2, world.shape[1] * world.shape[2], 3))  # per hand
    d = hs.hand_sdf(pts.reshape(T * 2, -1, 3), joints_Tx2x21x3.reshape(T * 2, 21, 3)).reshape(T, 2, 2, -1)
    return jnp.clip(d.min(1), 0.0, CLIP_M).reshape(T, 2, -1)


def _nearest(src_Nx3, dst_Mx3):
    d2 = ((src_Nx3[:, None] - dst_Mx3[None]) ** 2).sum(-1)
    return d2.argmin(1), np.sqrt(d2.min(1))


def mappings(dense_2xNx3, k, s_o):
    """For each scheme: per part, the indices (into that part's dense samples) of its mapped points."""
    b2 = np.asarray(basis_points(2 * k, seed=0))
    b1 = b2[:k]  # the same kind of draw, K points (P-BPS maps each to both parts: 2K features)
    union = np.concatenate([dense_2xNx3[TOP], dense_2xNx3[BOTTOM]])
    part_of = np.repeat([TOP, BOTTOM], len(dense_2xNx3[TOP]))
    out = {}
    for name, basis, scale in (("U-BPS", 0.5 * b2, 1.0), ("PA-BPS", b2, s_o)):
        idx = np.argmin(((union[None] * scale - basis[:, None]) ** 2).sum(-1), 1)
        idx = np.unique(idx)  # basis points sharing a nearest point add nothing
        out[name] = [idx[part_of[idx] == p] - (p == BOTTOM) * len(dense_2xNx3[TOP]) for p in (TOP, BOTTOM)]
    mapped = map_basis(dense_2xNx3, b1, s_o)                                          # (2, K, 3)
    out["P-BPS"] = [np.unique(_nearest(mapped[p], dense_2xNx3[p])[0]) for p in (TOP, BOTTOM)]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--k", type=int, default=64)
    ap.add_argument("--clips", type=int, default=0, help="first N clips (0: all)")
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    ds = Dataset.open(a.data)
    ann = open_object_annotations(a.data)
    n = len(ann["objects"]) if not a.clips else min(a.clips, len(ann["objects"]))
    err = {s: {"top": [], "bottom": [], "whole": [], "cover_top_mm": [], "cover_bottom_mm": [], "top_points": [], "bottom_points": []}
           for s in ("U-BPS", "PA-BPS", "P-BPS")}
    cats = {}
    by_cat = {}
    for i in range(n):
        rec = ann["objects"][i]
        obj = clip_object(rec)
        dense = np.stack([np.asarray(surface_samples(obj, p, N_DENSE, 1000 + p)[0]) for p in (TOP, BOTTOM)])
        s_o = float(object_scale(obj, jnp.asarray(dense), SCALE_ANGLE.get(rec["category"], DEFAULT_SCALE_ANGLE)))
        gt = np.asarray(_dense_contact(jnp.asarray(dense), jnp.asarray(ann["object_state"][i], jnp.float32),
                                       jnp.asarray(ds.motion[i], jnp.float32)))       # (T, 2, N)
        for scheme, idx in mappings(dense, a.k, s_o).items():
            e = {}
            for p, name in ((TOP, "top"), (BOTTOM, "bottom")):
                if len(idx[p]) == 0:  # no basis point reached this part: every value comes from... nothing
                    nn, cover = None, np.full(N_DENSE, np.nan)
                    e[name] = float(np.abs(gt[:, p] - CLIP_M).mean())  # the map says "far" everywhere
                else:
                    nn, cover = _nearest(dense[p], dense[p][idx[p]])
                    e[name] = float(np.abs(gt[:, p] - gt[:, p][:, idx[p]][:, nn]).mean())
                err[scheme][f"cover_{name}_mm"].append(1000 * float(np.nanmean(cover)) if len(idx[p]) else np.nan)
                err[scheme][name].append(100 * e[name])
            err[scheme]["whole"].append(100 * (e["top"] + e["bottom"]) / 2)
            by_cat.setdefault(rec["category"], {}).setdefault(scheme, []).append(100 * e["top"])
            err[scheme]["top_points"].append(len(idx[TOP]))
            err[scheme]["bottom_points"].append(len(idx[BOTTOM]))
        cats[rec["category"]] = cats.get(rec["category"], 0) + 1
    rows = {s: {k: round(float(np.nanmean(v)), 4) for k, v in d.items()} for s, d in err.items()}
    doc = {"data": str(a.data), "clips": n, "k": a.k, "categories": cats, "contact_clip_m": CLIP_M,
           "dense_samples_per_part": N_DENSE, "contact_map_error_cm_and_coverage": rows,
           "top_part_error_cm_by_category": {c: {s: round(float(np.mean(v)), 4) for s, v in d.items()}
                                             for c, d in sorted(by_cat.items())}}
    print(json.dumps(doc, indent=1))
    if a.out:
        Path(a.out).write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
