"""Two hands that take an articulated object and move it: the grab and use programs (issue 52 item 2).

A clip (60 frames at 30 fps, the project's clip) runs one program after ARCTIC's two kinds of sequence:

- **grab**: the angle stays constant; both hands take the object, lift it, carry it sideways and turn it (a yaw,
  with a tilt that comes and goes while it is in the air) and put it down again, then let go.
- **use**: the object stays on the table; one hand holds the bottom part, the other takes the top part near its
  free edge and opens it, closes it, or (scissors) snips it open and shut.

One hand holds the bottom part and the other the top part ("split"), or both hands hold one part ("pair", grab
only). Each hand reaches in along its grasp's approach normal with the template's open hand, closes its fingers
(object_grasp.solve_grasp found each finger's curl), holds, opens its fingers and withdraws along the normal.
The object moves only while both hands hold it, so a lifted object is always held. While a hand holds, its wrist
is the held part's pose times a fixed local pose (the grasp), so its contacts cannot slide.

Generation order per chunk (one rng, ``default_rng([seed, chunk_index])``): programs and object instances →
surface samples → grasp candidates → grasp solve (jit) → object trajectory → hand trajectories → world → the
hand corpus's canonical frame (skeleton.canonicalize's rotation, right wrist at the origin in frame 0).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from handx_jax import skeleton as sk
from handx_jax.synthesis import hand as H
from handx_jax.objects import BOTTOM, CATEGORIES, TOP, sample_instance, surface_samples
from handx_jax.synthesis import object_grasp as G
from handx_jax.synthesis import object_templates as OT
from handx_jax.synthesis.programs import smoothstep

PROGRAMS = ("grab", "use")
NO_PART = -1
ANGLE_SAMPLES = 4
# Where in the clip's angle range [lo, hi] the grasps are solved (fractions; the filter then checks every frame).
# Denser near the closed end: generator version 2's even spacing let the part that closes reach a hand between
# 0 and a third of the range (measured: the laptop's base hand inside the closing screen at 2-10 degrees, the
# commonest depth rejection); the wide end of the range swings the held part away from the other one.
ANGLE_FRACTIONS = np.array([0.0, 0.1, 0.4, 1.0])
# A candidate's pad counts as touching when its distal phalanx's axis spheres are this close (the filter's 3 mm on
# the surface points, less the spheres' <= 0.7 mm bulge error; object_grasp.AXIS_SAMPLES).
PAD_SELECT_M = 0.0023


@lru_cache(maxsize=None)
def max_primitives() -> int:
    """Every object is padded to this many primitives (rows of part -1, which no part mask selects), so one
    compiled program serves all categories and instances: the most any category has (a category's primitive
    count does not depend on its sizes)."""
    return max(int(sample_instance(c, 0).n_primitives) for c in CATEGORIES)


@dataclass(frozen=True)
class ObjectSynthConfig:
    chunk_size: int = 32
    clip_len: int = sk.CLIP_LEN
    fps: int = sk.FPS
    categories: tuple = tuple(CATEGORIES)
    grab_prob: float = 0.5               # of clips whose category can be lifted (object_templates.GRAB)
    pair_prob: float = 0.35              # of grab clips whose category has a part both hands take (PAIRED)
    # Grasp anchors tried per hand; the clearest with most pads on its part is kept. 2 (version 2: 3): the grasp
    # solve is most of the CPU and a third candidate kept only ~3 % more clips (6 chunks of seed 0: 143 kept of
    # 192 with 2, 147 with 3; CPU per kept clip 0.081 against 0.091 s).
    candidates: int = 2
    surface_samples: int = 1024          # per part, for the templates' anchors
    hand_scale_range: tuple = (0.85, 1.15)
    bone_jitter: float = 0.03
    roll_deg: float = 15.0               # palm roll about the approach normal, uniform +-
    approach_m: tuple = (0.08, 0.14)     # how far out along the normal a hand starts and ends
    lift_m: tuple = (0.06, 0.16)
    carry_m: tuple = (0.0, 0.15)
    turn_deg: tuple = (-50.0, 50.0)
    tilt_deg: tuple = (0.0, 25.0)
    place_m: tuple = ((-0.08, 0.08), (0.30, 0.42))   # object's rest position (x, y), in front of the person
    yaw_deg: float = 25.0                # rest heading, uniform +-


def pad_object(obj, n=None):
    """``obj`` with its primitive table padded to ``n`` rows (tiny boxes of part -1 far away) and the category
    "mixed": one jit trace for every category."""
    n = max_primitives() if n is None else n
    P = obj.kind_P.shape[-1]
    k = n - P
    if k < 0:
        raise ValueError(f"{obj.category} has {P} primitives; the padding is {n}")
    # numpy, not jnp: 5 eager device ops per field and clip cost more than the chunk's whole physics check.
    def pad(a, v):
        a = np.asarray(a)
        return np.concatenate([a, np.broadcast_to(np.asarray(v, a.dtype), (k,) + a.shape[1:])])
    return dataclasses.replace(
        obj, kind_P=pad(obj.kind_P, 0), part_P=pad(obj.part_P, NO_PART), size_Px3=pad(obj.size_Px3, 1e-3),
        rot_Px3x3=pad(obj.rot_Px3x3, np.eye(3)), trans_Px3=pad(obj.trans_Px3, 100.0), category="mixed")


def stack_objects(objs):
    return jax.tree.map(lambda *a: jnp.asarray(np.stack([np.asarray(x) for x in a])), *objs)


@lru_cache(maxsize=4)
def _sampler(n: int):
    def both(obj, key):
        k0, k1 = jax.random.split(key)
        p0, n0 = surface_samples(obj, TOP, n, k0)
        p1, n1 = surface_samples(obj, BOTTOM, n, k1)
        return jnp.stack([p0, p1]), jnp.stack([n0, n1])
    return jax.jit(jax.vmap(both))


_solve = jax.jit(jax.vmap(G.solve_grasp))
def part_poses(states_NxTx7: np.ndarray):
    """World-from-canonical transforms of both parts per frame, float64 (objects.part_pose's rule, in numpy: the
    top part turns by the angle about -z, then both take the global rotation and translation): R (N, T, 2, 3, 3),
    t (N, T, 2, 3)."""
    s = np.asarray(states_NxTx7, np.float64)
    lead = s.shape[:-1]
    Rg = Rotation.from_rotvec(s[..., 1:4].reshape(-1, 3)).as_matrix()
    Rh = Rotation.from_rotvec(np.outer(-s[..., 0].reshape(-1), [0.0, 0.0, 1.0])).as_matrix()
    R = np.stack([Rg @ Rh, Rg], 1).reshape(lead + (2, 3, 3))
    t = np.broadcast_to(s[..., None, 4:7], lead + (2, 3))
    return R, t


@dataclass
class ObjectChunk:
    joints: np.ndarray       # (N, T, 2, 21, 3) float32, canonical frame (as the hand corpus's clips)
    states: np.ndarray       # (N, T, 7) float32: angle, axis-angle, translation, same frame
    held: np.ndarray         # (N, T, 2) int8: the part each hand holds (objects.TOP / BOTTOM), -1 none
    contact_fingers: np.ndarray  # (N, 2, 5) bool: the fingers whose closing met the object
    objects: list            # per clip: the padded ArticulatedObject
    programs: list[dict]     # per clip: category, instance seed, program, layout, per hand part and template
    ok: np.ndarray           # (N,) bool: every hand found a grasp with >= 2 touching fingers
    samples: np.ndarray      # (N, 2, S, 3) the parts' surface samples (canonical frames) the anchors came from


def _phase_profiles(rng, n, cfg):
    """Per clip and hand: the frames the wrist arrives, the fingers close, they open, the wrist leaves."""
    T = cfg.clip_len
    arrive = rng.integers(7, 12, (n, 2))
    grip = arrive + rng.integers(4, 7, (n, 2))
    release = rng.integers(T - 16, T - 11, (n, 2))
    opened = release + rng.integers(4, 6, (n, 2))
    return arrive, grip, release, opened


def _ramp(t, a, b):
    """0 before frame a, 1 after b, smoothstep between; (n, 2, T) from (n, 2) frames."""
    return smoothstep((t[None, None] - a[..., None]) / np.maximum(b - a, 1)[..., None])


def _angle_trajectory(rng, category, program, t, start, end):
    """(T,) angle and the use kind. ``start``..``end`` is the manipulation window (both hands hold)."""
    lo = float(CATEGORIES[category].angle_range[0])
    top = OT.USE_MAX_ANGLE[category]
    if program == "grab":
        a0 = 0.0 if rng.random() < 0.7 else rng.uniform(0.2, 0.6) * top
        return np.full(t.shape, a0), "carry"
    kind = rng.choice(OT.USE_KINDS.get(category, OT.DEFAULT_USE_KINDS))
    hi = rng.uniform(0.55, 1.0) * top
    s = smoothstep((t - start) / max(end - start, 1))
    if kind == "open":
        return lo + (hi - lo) * s, kind
    if kind == "close":
        return hi - (hi - lo) * s, kind
    cycles = int(rng.integers(2, 4))
    return lo + (hi - lo) * 0.5 * (1 - np.cos(2 * np.pi * cycles * s)), kind


def _global_trajectory(rng, t, start, end, cfg, R_rest, t_rest):
    """Rotation (T, 3, 3) and translation (T, 3) of the object: at rest, or lifted, carried and turned between
    ``start`` and ``end`` and put down again (the tilt comes and goes with the height, so it lands flat)."""
    u = np.clip((t - start) / max(end - start, 1), 0.0, 1.0)
    height = smoothstep(u / 0.3) * smoothstep((1.0 - u) / 0.3)
    move = smoothstep((u - 0.2) / 0.6)
    lift = rng.uniform(*cfg.lift_m)
    carry = rng.uniform(*cfg.carry_m) * rng.choice([-1.0, 1.0])
    turn = math.radians(rng.uniform(*cfg.turn_deg))
    tilt = math.radians(rng.uniform(*cfg.tilt_deg)) * rng.choice([-1.0, 1.0])
    tilt_axis = rng.choice([0, 1])
    trans = t_rest[None] + np.stack([carry * move, np.zeros_like(u), lift * height], -1)
    yaw = Rotation.from_rotvec(np.outer(turn * move, [0.0, 0.0, 1.0]))
    tl = Rotation.from_rotvec(np.outer(tilt * height ** 2, np.eye(3)[tilt_axis]))
    R = (yaw * tl).as_matrix() @ R_rest
    return R, trans, dict(lift_m=lift, carry_m=carry, turn_deg=math.degrees(turn), tilt_deg=math.degrees(tilt))


def _rest_translation(R_rest, pts_2xSx3, xy):
    """Translation that stands the object on the table (z = 0) at ``xy``: its lowest sample touches it."""
    z = (pts_2xSx3.reshape(-1, 3) @ R_rest.T)[:, 2].min()
    return np.array([xy[0], xy[1], -z])


def synth_object_chunk(seed: int, chunk_index: int, cfg: ObjectSynthConfig = ObjectSynthConfig()) -> ObjectChunk:
    """``cfg.chunk_size`` clips, deterministic in (seed, chunk_index, cfg); chunks are independent."""
    rng = np.random.default_rng([seed, chunk_index, 0x0B7EC7])
    N, T, M = cfg.chunk_size, cfg.clip_len, cfg.candidates
    t = np.arange(T, dtype=np.float64)
    progs, objs = [], []
    for _ in range(N):
        cat = str(rng.choice(cfg.categories))
        inst = int(rng.integers(2 ** 31))
        program = "grab" if cat in OT.GRAB and rng.random() < cfg.grab_prob else "use"
        layout = "pair" if program == "grab" and cat in OT.PAIRED and rng.random() < cfg.pair_prob else "split"
        progs.append(dict(category=cat, instance_seed=inst, program=program, layout=layout))
        objs.append(pad_object(sample_instance(cat, inst)))
    batch = stack_objects(objs)
    keys = jax.random.split(jax.random.PRNGKey(int(rng.integers(2 ** 31))), N)
    pts, nrm = (np.asarray(a, np.float64) for a in _sampler(cfg.surface_samples)(batch, keys))   # (N, 2, S, 3)

    scale = rng.uniform(*cfg.hand_scale_range, N)
    geom = H.hand_geometry(scale, rng.uniform(-cfg.bone_jitter, cfg.bone_jitter, (N, 5, 3)))
    arrive, grip, release, opened = _phase_profiles(rng, N, cfg)
    start, end = grip.max(1) + 1, release.min(1) - 1

    # Programs → object trajectories (world) and each hand's template.
    R_obj = np.empty((N, T, 3, 3))
    t_obj = np.empty((N, T, 3))
    angle = np.empty((N, T))
    rows = []   # grasp candidates: (clip, hand, part, anchor, normal, finger, shape, anchor kind)
    for i, pr in enumerate(progs):
        cat = pr["category"]
        obj_up = np.asarray(objs[i].up_3, np.float64)
        R_rest = Rotation.from_rotvec([0, 0, math.radians(rng.uniform(-cfg.yaw_deg, cfg.yaw_deg))]).as_matrix() \
            @ OT.rest_rotation(cat, obj_up)
        xy = (rng.uniform(*cfg.place_m[0]), rng.uniform(*cfg.place_m[1]))
        t_rest = _rest_translation(R_rest, pts[i], xy)
        angle[i], pr["use"] = _angle_trajectory(rng, cat, pr["program"], t, start[i], end[i])
        if pr["program"] == "grab":
            R_obj[i], t_obj[i], pr["motion"] = _global_trajectory(rng, t, start[i], end[i], cfg, R_rest, t_rest)
        else:
            R_obj[i], t_obj[i] = R_rest, t_rest
        tpls = OT.TEMPLATES[cat]
        if pr["layout"] == "pair":
            roles = (OT.PAIRED[cat],) * 2
        elif tpls["top"].hand is not None:
            roles = ("bottom", "top") if tpls["top"].hand == sk.RIGHT else ("top", "bottom")
        else:
            # The hand on the top template's side takes the top part (scissors' upper ring is on the left); where
            # the top part spans both sides, either hand.
            tp = tpls["top"]
            idx, _ = OT.candidates(tp, pts[i, TOP], nrm[i, TOP], R_rest, 0.0, rng, 64)
            wx = ((pts[i, TOP, idx] - pts[i, TOP].mean(0)) @ R_rest[0]).mean() if len(idx) else 0.0
            right_top = wx > 0.02 if abs(wx) > 0.02 else rng.random() < 0.6
            roles = ("bottom", "top") if right_top else ("top", "bottom")
        pr["hands"] = []
        for h, role in enumerate(roles):
            tpl = tpls[role]
            side = -1.0 if h == sk.LEFT else 1.0
            idx, fdir = OT.candidates(tpl, pts[i, tpl.part], nrm[i, tpl.part], R_rest, side, rng, M)
            pr["hands"].append(dict(part=tpl.part, template=tpl.name,
                                    shape=tpl.shape, candidates=len(idx)))
            for c in range(M):
                if len(idx):
                    k = idx[c % len(idx)]
                    rows.append((i, h, tpl.part, pts[i, tpl.part, k], nrm[i, tpl.part, k], fdir[c % len(idx)],
                                 tpl.shape, tpl.anchor, G.anchor_offset(tpl.anchor, tpl.inset)))
                else:  # no anchor: a placeholder row, and the clip is dropped
                    rows.append((i, h, tpl.part, np.zeros(3), np.array([0, 0, 1.0]), np.array([0, 1.0, 0]),
                                 tpl.shape, tpl.anchor, 0.0))

    # Solve every candidate in one call (N * 2 * M rows: a fixed shape, one compile).
    clip_r = np.array([r[0] for r in rows])
    hand_r = np.array([r[1] for r in rows])
    part_r = np.array([r[2] for r in rows], np.int32)
    # The grasp must clear the other part at every angle of the clip: four angles across its range (the rest is
    # checked on every frame by the physics filter, object_physics.py).
    ang_lo, ang_hi = angle.min(1), angle.max(1)
    angles = ang_lo[clip_r, None] + np.asarray(ANGLE_FRACTIONS)[None] * (ang_hi - ang_lo)[clip_r, None]
    g_rows = {k: v[clip_r] for k, v in geom.items()}
    shapes = [G.SHAPES[r[6]] for r in rows]
    res = _solve(jax.tree.map(lambda a: a[clip_r], batch), jnp.asarray(part_r), jnp.asarray(angles, jnp.float32),
                 {k: jnp.asarray(v, jnp.float32) for k, v in g_rows.items()},
                 jnp.asarray(np.where(hand_r == sk.LEFT, -1.0, 1.0), jnp.float32),
                 jnp.asarray(np.stack([r[3] for r in rows]), jnp.float32),
                 jnp.asarray(np.stack([r[4] for r in rows]), jnp.float32),
                 jnp.asarray(np.stack([r[5] for r in rows]), jnp.float32),
                 jnp.asarray(np.radians(rng.uniform(-cfg.roll_deg, cfg.roll_deg, len(rows))), jnp.float32),
                 jnp.asarray(np.stack([s[0] for s in shapes]), jnp.float32),
                 jnp.asarray(np.stack([s[1] for s in shapes]), jnp.float32),
                 jnp.asarray(np.stack([G.anchor_weights(r[7]) for r in rows])),
                 jnp.asarray([r[8] for r in rows], jnp.float32))
    res = {k: np.asarray(v, np.float64) for k, v in res.items()}
    # Per hand the candidate with the most fingers whose pads touch (what the physics filter asks of a holding hand:
    # >= 2 pads within 3 mm), then the most touching fingers, among those whose hand stays clear of the object.
    # A finger can meet an edge with its proximal phalanx and keep its pad off it; counting any touching finger
    # picked such grasps and the filter then dropped them.
    score = (res["pad"] <= PAD_SELECT_M).sum(-1) + 0.1 * res["contact"].sum(-1) + 10.0 * (res["clear"] >= -0.0005)
    score = score.reshape(N, 2, M)
    best = score.argmax(-1)
    pick = (np.arange(N)[:, None] * 2 + np.arange(2)[None]) * M + best               # (N, 2) row index
    ok = np.array([all(h["candidates"] > 0 for h in pr["hands"]) for pr in progs])
    contact = res["contact"][pick] > 0.5
    ok &= (contact.sum(-1) >= 2).all(-1)

    # Hand trajectories in the held part's frame: reach in along the normal, close, hold, open, withdraw.
    pose_open = np.stack([G.SHAPES[rows[p][6]][0] for p in pick.reshape(-1)]).reshape(N, 2, 16)
    pose_grip = res["pose"][pick]
    k_close = _ramp(t, arrive, grip) * (1.0 - _ramp(t, release, opened))           # (N, 2, T)
    reach = np.maximum(1.0 - _ramp(t, np.zeros_like(arrive), arrive), _ramp(t, opened, np.full_like(opened, T - 1)))
    out = rng.uniform(*cfg.approach_m, (N, 2, 1))
    pose = pose_open[:, :, None] + k_close[..., None] * (pose_grip - pose_open)[:, :, None]      # (N, 2, T, 16)
    gl = {k: v.reshape((N, 1, 1) + v.shape[1:]) for k, v in geom.items()}
    mirror = np.ones((1, 2, 1, 1, 3))
    mirror[0, sk.LEFT, 0, 0, 0] = -1.0   # the left hand is the right one mirrored in x (synth.py's rule)
    local = H.hand_fk(H.clip_to_limits(pose), gl) * mirror
    Rg, wg = res["R"][pick], res["wrist"][pick]                                      # (N, 2, 3, 3), (N, 2, 3)
    normal = Rg[..., :, 2]
    wrist = wg[:, :, None] + (out * reach)[..., None] * normal[:, :, None]            # (N, 2, T, 3)
    in_part = np.einsum("nhij,nhtkj->nhtki", Rg, local) + wrist[:, :, :, None]

    states = np.concatenate([angle[..., None], Rotation.from_matrix(R_obj.reshape(-1, 3, 3)).as_rotvec()
                             .reshape(N, T, 3), t_obj], -1)
    Rp, tp = part_poses(states)                                              # (N, T, 2, 3, 3)
    hp = np.array([[h["part"] for h in pr["hands"]] for pr in progs])                # (N, 2)
    Rh = np.take_along_axis(Rp, hp[:, None, :, None, None], 2)                       # (N, T, 2, 3, 3)
    th = np.take_along_axis(tp, hp[:, None, :, None], 2)
    joints = np.einsum("nthij,nhtkj->nthki", Rh, in_part) + th[:, :, :, None]       # (N, T, 2, 21, 3)

    held = np.where((k_close >= 1.0 - 1e-9).transpose(0, 2, 1), hp[:, None, :], -1).astype(np.int8)
    joints_c, states_c = canonical_frame(joints, states)
    for i, pr in enumerate(progs):
        for h in range(2):
            pr["hands"][h]["contact_fingers"] = int(contact[i, h].sum())
    return ObjectChunk(joints=joints_c.astype(np.float32), states=states_c.astype(np.float32), held=held,
                       contact_fingers=contact, objects=objs, programs=progs, ok=ok,
                       samples=pts.astype(np.float32))


def canonical_frame(joints_NxTx2x21x3: np.ndarray, states_NxTx7: np.ndarray):
    """The hand corpus's frame (skeleton.canonical_rotation of frame 0, right wrist at the origin in frame 0),
    applied to the hands and to the object's state (its rotation and translation; the angle is unchanged)."""
    J = np.empty_like(joints_NxTx2x21x3)
    S = np.empty_like(states_NxTx7)
    for i in range(len(J)):
        R = sk.canonical_rotation(joints_NxTx2x21x3[i])
        o = joints_NxTx2x21x3[i, 0, sk.RIGHT, 0]
        J[i] = (joints_NxTx2x21x3[i] - o) @ R.T
        Rg = R @ Rotation.from_rotvec(states_NxTx7[i, :, 1:4]).as_matrix()
        S[i, :, 0] = states_NxTx7[i, :, 0]
        S[i, :, 1:4] = Rotation.from_matrix(Rg).as_rotvec()
        S[i, :, 4:7] = (states_NxTx7[i, :, 4:7] - o) @ R.T
    return J, S
