"""Generated hand-object clips (task ``object2motion``): the file ``handx generate`` writes, and its scoring by
BimArt's metrics (metrics/objects.py; ``handx eval objects``).

File (``.npz``): ``joints`` (N, S, F, 2, 21, 3) world metres, S samples per object trajectory; ``object_state``
(N, F, 7) beside them (ARCTIC's layout: angle, axis-angle, translation); ``contact`` (N, S, F, 2, 2, K) the contact
maps the motion was conditioned on (m); ``bps_points`` (N, 2, K, 3); ``records`` the clips' object records (JSON;
``synthesis.object_build.clip_object`` rebuilds each object); ``source`` the corpus and ``clips`` its indices, whose
ground-truth hands give the part contact F1. A file made from an ARCTIC sequence (``--arctic ROOT --seq S``) has no
corpus: its records say ``{"source": "arctic", "seq", "start", "mesh": u}``, the object's mesh rides in the file
(``mesh_tri`` (U, F, 3, 3) metres, ``mesh_part`` (U, F), ``mesh_angle_range`` (U, 2), as ``interop.arctic.mesh_arrays``
gives them) so it is scored without the ARCTIC folder, and ``gt_joints`` (N, F, 2, 21, 3) holds the sequence's
hands where ARCTIC's processed joints exist (else the part contact F1 is not scored).

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
MESH_KEYS = ("mesh_tri", "mesh_part", "mesh_angle_range")
OPTIONAL = (*MESH_KEYS, "gt_joints")
CONTACT_MAX_M = 0.2


def write(path, *, joints, object_state, contact, bps_points, records, clips, source, mesh_tri=None, mesh_part=None,
          mesh_angle_range=None, gt_joints=None) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    extra = {}
    if mesh_tri is not None:
        extra.update(mesh_tri=np.asarray(mesh_tri, np.float32), mesh_part=np.asarray(mesh_part, np.int32),
                     mesh_angle_range=np.asarray(mesh_angle_range, np.float32))
    if gt_joints is not None:
        extra["gt_joints"] = np.asarray(gt_joints, np.float32)
    np.savez(path, joints=np.asarray(joints, np.float32), object_state=np.asarray(object_state, np.float32),
             contact=np.asarray(contact, np.float16), bps_points=np.asarray(bps_points, np.float32),
             records=np.asarray(json.dumps(records)), clips=np.asarray(clips, np.int64), source=np.asarray(str(source)),
             **extra)
    return path


def read(path) -> dict:
    """A generated hand-object file, checked (infra.readers: a garbage, truncated or pickled file is one line)."""
    from handx_jax.infra.readers import read_npz

    p = Path(path)
    if not p.exists():
        raise DataError("no such generated file", path=p)
    arrays = read_npz(p)
    missing = [k for k in KEYS if k not in arrays]
    if missing:
        raise DataError(f"not a hand-object generation (handx generate --task object2motion): missing "
                        f"{', '.join(missing)}", path=p)
    out = {k: arrays[k] for k in (*KEYS, *OPTIONAL) if k in arrays}
    try:
        out["records"] = json.loads(str(out["records"]))
    except ValueError as e:
        raise DataError(f"records: not JSON ({e})", path=p, field="records") from None
    out["source"] = str(out["source"])
    N = out["joints"].shape[0] if out["joints"].ndim == 6 else -1
    if N < 0 or out["joints"].shape[2:] != (out["object_state"].shape[1], 2, 21, 3) or \
            out["object_state"].shape[0] != N or len(out["records"]) != N or \
            not all(isinstance(r, dict) for r in out["records"]):
        raise DataError(f"joints {out['joints'].shape}, object_state {out['object_state'].shape} and "
                        f"{len(out['records'])} records do not describe the same clips: (N, S, F, 2, 21, 3), "
                        f"(N, F, 7), N", path=p)
    meshes = [r["mesh"] for r in out["records"] if "mesh" in r]
    if meshes:
        if any(k not in out for k in MESH_KEYS):
            raise DataError(f"records name meshes but the file lacks {', '.join(k for k in MESH_KEYS if k not in out)}",
                            path=p)
        U = len(out["mesh_tri"])
        if not all(isinstance(u, int) and 0 <= u < U for u in meshes):
            raise DataError(f"a record's mesh index is not one of the file's {U} meshes", path=p, field="records")
    if "gt_joints" in out and out["gt_joints"].shape != (N, *out["joints"].shape[2:]):
        raise DataError(f"gt_joints {out['gt_joints'].shape}, expected {(N, *out['joints'].shape[2:])}", path=p,
                        field="gt_joints")
    out["path"] = str(p)
    return out


def objects_of(gen: dict) -> list:
    """The ArticulatedObject of each clip: a corpus clip's rebuilt from its record (category, instance seed), an
    ARCTIC sequence's from the mesh the file carries."""
    from handx_jax.interop.arctic import object_from_mesh_arrays
    from handx_jax.synthesis.object_build import clip_object

    built: dict[int, object] = {}
    out = []
    for r in gen["records"]:
        if "mesh" in r:
            u = r["mesh"]
            if u not in built:
                built[u] = object_from_mesh_arrays(gen["mesh_tri"][u], gen["mesh_part"][u], str(r.get("category", "")),
                                                   gen["mesh_angle_range"][u], path=gen.get("path"))
            out.append(built[u])
        else:
            try:
                out.append(clip_object(r))
            except (KeyError, TypeError, ValueError) as e:
                raise DataError(f"a record names neither a corpus object (category, instance_seed) nor a mesh: {e}",
                                path=gen.get("path"), field="records") from None
    return out


def ground_truth(gen: dict):
    """The ground-truth hands (N, F, 2, 21, 3) the part contact F1 compares with: the file's own (an ARCTIC
    sequence's), else the source corpus's clips where that corpus is still there; None otherwise."""
    if "gt_joints" in gen:
        return np.asarray(gen["gt_joints"], np.float32)
    if any(r.get("source") == "arctic" for r in gen["records"]):
        return None
    if gen["source"] and Path(gen["source"]).exists():
        from handx_jax.dataset.format import Dataset

        return np.asarray(Dataset.open(gen["source"]).motion[gen["clips"]], np.float32)
    return None


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

    J, states = gen["joints"], gen["object_state"]
    N, S = J.shape[:2]
    rows, muls, cms, per_clip = [], [], [], []
    objects = objects_of(gen)
    for i in range(N):
        obj = objects[i]
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


def caption_source(gen: dict):
    """(the source corpus, its clips) whose three-text captions the generated hands were made for, or a line saying
    why the file has none: an ARCTIC sequence carries no captions, a moved or deleted corpus cannot be read."""
    if any(r.get("source") == "arctic" for r in gen["records"]):
        return "the clips come from an ARCTIC sequence, which carries no captions: no text metrics"
    if not gen["source"] or not Path(gen["source"]).exists():
        return f"the source corpus {gen['source']!r} is not there: its captions are unknown, no text metrics"
    if len(gen["clips"]) < 2:
        return "one clip: R-Precision, FID and diversity compare clips with each other, no text metrics"
    from handx_jax.dataset.format import Dataset

    ds = Dataset.open(gen["source"])
    if not len(ds.texts) or not all(ds.texts[int(c)].get("left") for c in gen["clips"]):
        return f"the source corpus {gen['source']} has no captions for these clips: no text metrics"
    return ds, np.asarray(gen["clips"], np.int64)


def text_scores(ev, gen: dict, ds, clips, cfg):
    """The text evaluator's metrics (R-Precision, matching score, FID, diversity, ...; ``scoring``'s Table 2 row)
    of the generated hands against their clips' captions at the evaluator's level, and the same clips' ground truth
    scored alike: (generated, ground truth) ``EvalResult``s.

    The dataset-evaluator pair check every other command makes is skipped on purpose: a hand-object corpus is outside
    every text evaluator's training data (the standard one's is the two-hand corpus), so these numbers read only
    beside the ground truth's own row on the same clips, never beside a hand corpus's. Nothing is cached (the
    reference cache's key is a corpus the evaluator scores)."""
    from handx_jax.evaluation.reference import reference_embeddings
    from handx_jax.evaluation.scoring import check_motion_range, evaluate_embeddings_and_motion

    gen_GxNxFx2x21x3 = np.swapaxes(np.asarray(gen["joints"], np.float32), 0, 1)
    for g in range(gen_GxNxFx2x21x3.shape[0]):
        for i, c in enumerate(clips):
            check_motion_range(gen_GxNxFx2x21x3[g, i], clip=ds.ids[int(c)])
    gt = np.asarray(ds.motion[clips], np.float32)
    ref = reference_embeddings(ev, ev.captions(ds, clips), gt, cache=False)
    meta = {"reference": str(ds.root), "out_of_domain": True}
    generated = evaluate_embeddings_and_motion(ev, ref.text_NxD, gen_GxNxFx2x21x3, gt, cfg, gt_NxD=ref.motion_NxD,
                                               meta={**meta, "ground_truth": False})
    truth = evaluate_embeddings_and_motion(ev, ref.text_NxD, gt[None], gt, cfg, gt_NxD=ref.motion_NxD,
                                           gen_GxNxD=ref.motion_NxD[None], meta={**meta, "ground_truth": True})
    return generated, truth
