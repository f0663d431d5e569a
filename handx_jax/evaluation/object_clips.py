"""Generated hand-object clips (task ``object2motion``): the file ``handx generate`` writes, and its scoring by
BimArt's metrics (metrics/objects.py; ``handx eval objects``).

File (``.npz``): ``joints`` (N, S, F, 2, 21, 3) world metres, S samples per object trajectory; ``object_state``
(N, F, 7) beside them (ARCTIC's layout: angle, axis-angle, translation); ``contact`` (N, S, F, 2, 2, K) the contact
maps the motion was conditioned on (m); ``bps_points`` (N, 2, K, 3); ``records`` the clips' object records (JSON;
``synthesis.object_build.clip_object`` rebuilds each object); ``source`` the corpus and ``clips`` its indices, whose
ground-truth hands give the part contact F1.

Scores (means over clips and samples): Pen 1cm / 5mm / depth, Con, Art, Accel, part contact F1 against the
ground truth, CM (the L1, cm, between the contact map of the generated hands — each mapped point's distance to the
hand surface, clipped at 0.2 m — and the map they were conditioned on) and Mul over each trajectory's samples.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import hand_surface as hs
from handx_jax.infra.errors import DataError
from handx_jax.metrics import objects as M
from handx_jax.objects import surface_samples
from handx_jax.objects.features import mapped_points_world

KEYS = ("joints", "object_state", "contact", "bps_points", "records", "clips", "source")
CONTACT_MAX_M = 0.2


def write(path, *, joints, object_state, contact, bps_points, records, clips, source) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, joints=np.asarray(joints, np.float32), object_state=np.asarray(object_state, np.float32),
             contact=np.asarray(contact, np.float16), bps_points=np.asarray(bps_points, np.float32),
             records=np.asarray(json.dumps(records)), clips=np.asarray(clips, np.int64), source=np.asarray(str(source)))
    return path


def read(path) -> dict:
    p = Path(path)
    if not p.exists():
        raise DataError("no such generated file", path=p)
    with np.load(p, allow_pickle=False) as z:
        missing = [k for k in KEYS if k not in z.files]
        if missing:
            raise DataError(f"not a hand-object generation (handx generate --task object2motion): missing "
                            f"{', '.join(missing)}", path=p)
        out = {k: z[k] for k in KEYS}
    out["records"] = json.loads(str(out["records"]))
    out["source"] = str(out["source"])
    return out


@jax.jit
def _contact_of_hands(bps_2xKx3, states_Tx7, joints_Tx2x21x3):
    V = mapped_points_world(bps_2xKx3, states_Tx7)                                   # (T, 2, K, 3)
    T = V.shape[0]
    pts = jnp.broadcast_to(V.reshape(T, 1, -1, 3), (T, 2, V.shape[1] * V.shape[2], 3))
    d = hs.hand_sdf(pts.reshape(T * 2, -1, 3), joints_Tx2x21x3.reshape(T * 2, 21, 3))
    return jnp.clip(d.reshape(T, 2, 2, -1), 0.0, CONTACT_MAX_M)                     # (T, hand, part, K)


def _clip_mean(values) -> float:
    v = np.asarray(values, np.float64)
    return float(v[np.isfinite(v)].mean()) if np.isfinite(v).any() else float("nan")


def score(gen: dict, gt_joints=None) -> dict:
    """BimArt's metrics of a generation (``read``); ``gt_joints`` (N, F, 2, 21, 3) for the part contact F1.

    Each metric's point value is its mean over clips and samples; ``<metric>_ci`` is the 95% half-width of a
    bootstrap over clips (``metrics.prompt_mean_ci``) of each clip's mean over its samples, the interval the
    prediction benchmark uses (a clip's samples share its object and trajectory, so they are not independent)."""
    from handx_jax.metrics import prompt_mean_ci
    from handx_jax.synthesis.object_build import clip_object

    J, states = gen["joints"], gen["object_state"]
    N, S = J.shape[:2]
    rows, muls, cms, per_clip = [], [], [], []
    for i in range(N):
        obj = clip_object(gen["records"][i])
        samples = np.stack([np.asarray(surface_samples(obj, p, 512, 0)[0]) for p in (0, 1)])
        true = None
        if gt_joints is not None:
            true = M.part_contacts(M.hand_part_distances(obj, states[i], M.hand_points_from_joints(gt_joints[i])))
        pts_s, rows_i, cms_i = [], [], []
        for s in range(S):
            pts = M.hand_points_from_joints(J[i, s])
            pts_s.append(pts)
            rows_i.append(M.object_metrics(obj, states[i], pts, samples, true))
            got = np.asarray(_contact_of_hands(jnp.asarray(gen["bps_points"][i]), jnp.asarray(states[i]),
                                               jnp.asarray(J[i, s])))
            want = np.clip(np.asarray(gen["contact"][i, s], np.float32), 0.0, CONTACT_MAX_M)
            cms_i.append(100 * float(np.abs(got - want).mean()))
        rows += rows_i
        cms += cms_i
        clip = {k: _clip_mean([r[k] for r in rows_i]) for k in rows_i[0]}
        clip["obj_cm_cm"] = _clip_mean(cms_i)
        if S > 1:
            muls.append(M.obj_multimodality(np.stack(pts_s)))
            clip["obj_mul_cm"] = 100 * muls[-1]
        per_clip.append(clip)
    out = {k: float(np.nanmean([r[k] for r in rows])) for k in rows[0]}
    out["obj_cm_cm"] = float(np.mean(cms))
    out["obj_mul_cm"] = 100 * float(np.mean(muls)) if muls else float("nan")
    for k in [k for k in out if k in per_clip[0]]:
        out[f"{k}_ci"] = prompt_mean_ci([c[k] for c in per_clip])[1] if N > 1 else float("nan")
    out["clips"], out["samples"] = int(N), int(S)
    return out
