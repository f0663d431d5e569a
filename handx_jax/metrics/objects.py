"""BimArt's hand -> object metrics (BimArt §4 "Evaluation Metrics", Tab. 1, App. D Tab. II), named ``obj_*`` so
they cannot be confused with the inter-hand ones of hand_papers.py (whose "Pen 1cm" is hand -> hand).

Every per-frame metric reads one array: ``near_TxHx2``, each hand's least signed distance (metres, negative
inside) to each part (TOP, BOTTOM) over its hand-surface points (``hand_part_distances``; the surface is
hand_surface.py's, BimArt's MANO vertices stand-in). From it:

- Pen 1cm / 5mm (§4, App. D): % of frames where some hand-surface point is deeper than 1 cm / 5 mm inside the
  object (either part). ``obj_pen_depth`` is the mean over frames of the deepest point's depth (0 when none is
  inside): BimArt's l_pen (Eq. 11) sums such depths; the paper reports only the percentages.
- Con (§4): among the frames where the object moves, % where a hand is within 5 mm of it. BimArt does not say
  what "moves" means; here a frame moves when some surface sample of the object travels more than
  ``MOVE_TOL_M`` (1 mm, 3 cm/s at 30 fps, above mocap jitter) since the previous frame, by the global motion or
  the articulation.
- Art (§4): among the frames where the angle changes (|a_i - a_{i-1}| > ``ANGLE_TOL_RAD``), % where a hand is
  within 5 mm of the articulated (top) part.
- Mul (§4): the mean over sample pairs of the mean distance between corresponding hand points (BimArt: "mean
  average pairwise distance between all generated hand vertices", 10 samples per trajectory). Metres (Tab. 1: cm).
- Accel (Tab. 1, l_acc Eq. 12): the mean norm of h_i - 2 h_{i-1} + h_{i-2} over hand points and frames, in
  metres per frame^2 (BimArt's unit; Tab. 1 prints it in cm) and in m/s^2 (times fps^2).
- CM (§4, App. E Tab. III): the mean absolute difference between two contact maps (the l1 distance per entry).
- Part contact F1: contact per (frame, hand, part) is distance < 5 mm; F1 of predicted against ground truth.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import hand_surface as hs
from handx_jax import skeleton as sk
from handx_jax.objects import TOP, anonymous, object_sdf, to_world

CONTACT_M = 0.005        # "within 5 mm" (§4 Con / Art)
PEN_1CM_M, PEN_5MM_M = 0.01, 0.005
MOVE_TOL_M = 1e-3        # a frame "moves" when an object point travels more than this since the previous frame
ANGLE_TOL_RAD = 1e-3     # a frame's angle "changes" when it differs from the previous frame's by more than this


@jax.jit
def _hand_part_distances(obj, states_Tx7, points_TxHxPx3):
    def frame(state, pts_HxPx3):
        H, P = pts_HxPx3.shape[:2]
        _, per_part = object_sdf(obj, state, pts_HxPx3.reshape(H * P, 3))
        return jnp.min(per_part.reshape(2, H, P), axis=-1).T                        # (H, 2 parts)
    return jax.lax.map(lambda a: frame(*a), (states_Tx7, points_TxHxPx3))


def _bucket(n: int, step: int) -> int:
    return -(-n // step) * step


def hand_part_distances(obj, states_Tx7, points_TxHxPx3) -> np.ndarray:
    """(T, H, 2): each hand's least signed distance (m) to each part, over its surface points (world frame).
    Frames are padded to a multiple of 16 (repeating the last) and points to a multiple of 256 (repeating the
    first, which leaves a min unchanged), so clips of nearby lengths share one compiled program."""
    states = np.asarray(states_Tx7, np.float32)
    pts = np.asarray(points_TxHxPx3, np.float32)
    T, H, P = pts.shape[:3]
    states = np.concatenate([states, np.repeat(states[-1:], _bucket(T, 16) - T, 0)])
    pts = np.concatenate([pts, np.repeat(pts[-1:], _bucket(T, 16) - T, 0)])
    pts = np.concatenate([pts, np.repeat(pts[:, :, :1], _bucket(P, 256) - P, 2)], 2)
    return np.asarray(_hand_part_distances(anonymous(obj), states, pts), np.float64)[:T]


def hand_points_from_joints(joints_Tx2x21x3) -> np.ndarray:
    """(T, 2, P, 3): hand_surface.py's surface points of both hands (P = hand_surface.N_SURFACE_POINTS)."""
    j = np.asarray(joints_Tx2x21x3, np.float32)
    pts, _ = hs.surface_points(j.reshape(-1, sk.NUM_JOINTS, 3))
    return np.asarray(pts).reshape(j.shape[0], j.shape[1], -1, 3)


def obj_penetration(near_TxHx2) -> dict[str, float]:
    """Pen 1cm, Pen 5mm (% of frames) and the mean deepest depth (m) from ``hand_part_distances``."""
    depth_T = np.maximum(-np.min(np.asarray(near_TxHx2), axis=(1, 2)), 0.0)
    return {"obj_pen_1cm": 100.0 * float(np.mean(depth_T > PEN_1CM_M)),
            "obj_pen_5mm": 100.0 * float(np.mean(depth_T > PEN_5MM_M)),
            "obj_pen_depth_m": float(np.mean(depth_T))}


@jax.jit
def _object_points_world(obj, states_Tx7, samples_2xPx3):
    def frame(state):
        return jnp.concatenate([to_world(obj, p, state, samples_2xPx3[p]) for p in range(2)])
    return jax.vmap(frame)(states_Tx7)


def moving_frames(obj, states_Tx7, samples_2xPx3, tol_m: float = MOVE_TOL_M) -> np.ndarray:
    """(T,) bool: frames whose object (its surface samples ``samples_2xPx3``, part-canonical, from
    objects.surface_samples) moved more than ``tol_m`` since the previous frame; frame 0 never."""
    pts = np.asarray(_object_points_world(anonymous(obj), jnp.asarray(states_Tx7, jnp.float32),
                                          jnp.asarray(samples_2xPx3, jnp.float32)))
    step = np.linalg.norm(np.diff(pts, axis=0), axis=-1).max(axis=-1)
    return np.r_[False, step > tol_m]


def articulating_frames(states_Tx7, tol_rad: float = ANGLE_TOL_RAD) -> np.ndarray:
    """(T,) bool: frames whose angle differs from the previous frame's by more than ``tol_rad``; frame 0 never."""
    return np.r_[False, np.abs(np.diff(np.asarray(states_Tx7)[:, 0])) > tol_rad]


def obj_contact(near_TxHx2, moving_T) -> float:
    """Con: % of the moving frames with a hand within 5 mm of the object (NaN when nothing moves)."""
    moving = np.asarray(moving_T, bool)
    touch = np.min(np.asarray(near_TxHx2), axis=(1, 2)) < CONTACT_M
    return 100.0 * float(touch[moving].mean()) if moving.any() else float("nan")


def obj_articulation(near_TxHx2, articulating_T) -> float:
    """Art: % of the frames whose angle changes with a hand within 5 mm of the top part (NaN when none)."""
    art = np.asarray(articulating_T, bool)
    touch_top = np.min(np.asarray(near_TxHx2)[:, :, TOP], axis=1) < CONTACT_M
    return 100.0 * float(touch_top[art].mean()) if art.any() else float("nan")


def obj_multimodality(points_SxTxHxPx3) -> float:
    """Mul (m): mean over the S(S-1)/2 sample pairs of the mean distance between their corresponding points."""
    x = np.asarray(points_SxTxHxPx3, np.float64)
    S = x.shape[0]
    if S < 2:
        raise ValueError(f"Mul needs at least two samples of one trajectory, got {S}")
    flat = x.reshape(S, -1, 3)
    total = sum(np.linalg.norm(flat[a] - flat[b], axis=-1).mean() for a in range(S) for b in range(a + 1, S))
    return float(total / (S * (S - 1) / 2))


def obj_accel(points_TxHxPx3, fps: float = sk.FPS) -> dict[str, float]:
    """Accel: mean |h_i - 2 h_{i-1} + h_{i-2}| in m / frame^2 (BimArt's unit) and m / s^2."""
    x = np.asarray(points_TxHxPx3, np.float64)
    per_frame2 = float(np.linalg.norm(x[2:] - 2 * x[1:-1] + x[:-2], axis=-1).mean())
    return {"obj_accel_m_per_frame2": per_frame2, "obj_accel_m_s2": per_frame2 * fps ** 2}


def obj_cm_l1(map_a, map_b) -> float:
    """CM: the mean absolute difference between two contact maps of one shape (m for distance maps)."""
    a, b = np.asarray(map_a, np.float64), np.asarray(map_b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"contact maps differ in shape: {a.shape} vs {b.shape}")
    return float(np.mean(np.abs(a - b)))


def part_contacts(near_TxHx2, threshold_m: float = CONTACT_M) -> np.ndarray:
    """(T, H, 2) bool: hand h touches part p at frame t (within ``threshold_m``)."""
    return np.asarray(near_TxHx2) < threshold_m


def obj_part_contact_f1(pred_TxHx2, true_TxHx2) -> dict[str, float]:
    """Precision, recall and F1 of predicted (frame, hand, part) contacts against the ground truth's (NaN where
    undefined: no predicted or no true contacts)."""
    p, t = np.asarray(pred_TxHx2, bool), np.asarray(true_TxHx2, bool)
    tp, fp, fn = int((p & t).sum()), int((p & ~t).sum()), int((~p & t).sum())
    prec = tp / (tp + fp) if tp + fp else float("nan")
    rec = tp / (tp + fn) if tp + fn else float("nan")
    f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else float("nan")
    return {"obj_part_precision": prec, "obj_part_recall": rec, "obj_part_f1": f1}


def object_metrics(obj, states_Tx7, points_TxHxPx3, samples_2xPx3, true_contacts_TxHx2=None) -> dict[str, float]:
    """Every per-clip metric of one clip: Pen 1cm / 5mm / depth, Con, Art, Accel (and part F1 when ground-truth
    contacts are given). Mul and CM compare several clips or maps: ``obj_multimodality``, ``obj_cm_l1``."""
    near = hand_part_distances(obj, states_Tx7, points_TxHxPx3)
    out = obj_penetration(near)
    out["obj_con"] = obj_contact(near, moving_frames(obj, states_Tx7, samples_2xPx3))
    out["obj_art"] = obj_articulation(near, articulating_frames(states_Tx7))
    out.update(obj_accel(points_TxHxPx3))
    if true_contacts_TxHx2 is not None:
        out.update(obj_part_contact_f1(part_contacts(near), true_contacts_TxHx2))
    return out
