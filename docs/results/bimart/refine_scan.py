"""The refinement's weights on one sampling (refine_scan.json): sample a BimArt run once (generated contact maps,
guidance of the given strength) on a split's first LIMIT clips x 2, then refine that sample with each JSON of
RefineConfig fields (relative to the run's recorded sample.refine_cfg) and score each with `handx eval objects`'
metrics (evaluation/object_clips.score).

    SPLIT=val JAX_PLATFORMS=cpu .venv/bin/python docs/results/bimart/refine_scan.py RUN OBJ LIMIT STRENGTH \\
        '{}' '{"reduce": "mean", "w_pen": 10000, "w_proj": 1000}' ...
"""
import sys, json, time, dataclasses, numpy as np, jax, jax.numpy as jnp
from handx_jax.families.bimart import load, common as C, physics as PH, run as R
from handx_jax.models import bimart as BM
from handx_jax.objects.features import mapped_points_world
from handx_jax.evaluation import object_clips
from handx_jax.synthesis.object_build import clip_object
from handx_jax.synthesis.object_motion import stack_objects
run = load(sys.argv[1]); data_dir = sys.argv[2]; limit = int(sys.argv[3]); S = 2
print("contact", run.cfg.sample.contact, flush=True)
import os
clips = run.object_clips(data_dir, os.environ.get("SPLIT", "test"), limit)
print("split", os.environ.get("SPLIT", "test"), flush=True)
data = C.prepare(data_dir, clips, run.cfg.model, motion=False)
m, s = run.cfg.model, run.cfg.sample
N = len(clips); rows = np.repeat(np.arange(N), S)
V = np.asarray(jax.vmap(mapped_points_world)(jnp.asarray(data.bps_points), jnp.asarray(data.states)))
t0 = data.states[:, 0, 4:7]
x, c = R.sample_motion(run.contact.params, run.params, run.contact.cfg.model, m, jnp.asarray(data.obj[rows]),
    jnp.asarray(data.contact[rows]), jnp.asarray(V[rows]), jnp.asarray(t0[rows]), jnp.asarray(run.norm.mean),
    jnp.asarray(run.norm.std), jax.random.PRNGKey(0), jnp.float32(s.cfg_scale), jnp.float32(float(sys.argv[4]) if len(sys.argv) > 4 else 1.0),
    contact="generated", schedule=s.schedule, guide_at=s.guide_at)
H, D = PH.x_to_points((x - run.norm.mean) / run.norm.std, jnp.asarray(run.norm.mean), jnp.asarray(run.norm.std), jnp.asarray(t0[rows]), m)
objs = stack_objects([clip_object(data.records[i]) for i in rows])
states = jnp.asarray(data.states[rows])
gt = data.joints
def score(j):
    doc = {"joints": np.asarray(j).reshape(N, S, *j.shape[1:]), "object_state": data.states,
           "contact": np.asarray(c).reshape(N, S, m.frames, 2, 2, m.k), "bps_points": data.bps_points, "records": data.records}
    r = object_clips.score(doc, gt)
    return {k: round(r[k], 3) for k in ("obj_pen_1cm", "obj_pen_5mm", "obj_pen_depth_m", "obj_con", "obj_art", "obj_part_f1", "obj_cm_cm", "obj_accel_m_s2")}
print("raw", score(H[..., :21, :]), flush=True)
base = s.refine_cfg
for spec in sys.argv[5:]:
    kw = json.loads(spec)
    rc = dataclasses.replace(base, **kw)
    t = time.time()
    j = PH.refine_batch(H[..., :21, :], H, D, objs, states, m, rc)
    print(spec, score(j), "%.0fs" % (time.time() - t), flush=True)
