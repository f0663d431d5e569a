"""What the hand–object corpus keeps: its physics, measured on every frame, and the per-frame contact maps.

Measured per clip from the stored hands and object state (canonical frame), with the hand surface of
hand_surface.py and the objects' exact signed distances (issue 52 item 3):

- ``depth``: how deep each hand's deepest surface point is inside either part, per frame;
- ``interhand``: the two hands' signed surface distance per frame (negative: overlap depth);
- ``pad``: each fingertip pad's (distal capsule's surface points) closest distance to the object, per frame;
- ``drift``: how far each joint of a holding hand moves in its part's frame over the hold;
- the contact map (BimArt §3.2, Eq. 4): the distance from each basis-mapped object point (objects/bps.py, K per
  part) to each hand's surface (its capsule union), per frame.

A clip is kept when it passes :data:`LIMITS`; the build reports how many did not.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import hand_surface as hs
from handx_jax.objects import object_sdf, to_world
from handx_jax.synthesis.object_grasp import PAD_POINTS

# Issue 52 item 3: no surface point more than 2 mm inside either part; inter-hand overlap below 1 cm; the pads
# of the fingers that hold within 3 mm of the surface; a held hand drifts less than 0.1 mm in its part's frame.
LIMITS = {"depth_m": 0.002, "interhand_m": 0.01, "pad_m": 0.003, "drift_m": 1e-4}

_PAD_CAT = np.concatenate(PAD_POINTS)
_PAD_SEG = np.repeat(np.arange(5), [len(p) for p in PAD_POINTS])


# The check runs in two passes. Every surface point lies at its capsule's radius r from a centre on the capsule's
# axis (a ring's centre, or a fingertip's end for its rounded cap; hand_surface.surface_points), and a signed
# distance is 1-Lipschitz, so sdf(point) >= sdf(centre) - r: a coarse pass evaluates the object's SDF at the 71
# centres of a hand instead of its 573 points, and only the capsules whose bound comes within NEAR_M of either part
# get the exact pass on their points. Beyond NEAR_M no decision changes: a far point is outside (depth 0), not a
# touching pad (3 mm) and not in contact (5 mm); its reported distance is then the bound, not the exact value.
NEAR_M = 0.006
_C, _R, _K = hs.N_CAPSULES, len(hs.RINGS), hs.RING_POINTS
_TIPS = np.flatnonzero(hs.CAPSULE_IS_TIP)
_CENTRE_OF_POINT = np.concatenate([np.arange(_C * _R).repeat(_K), (_C * _R + np.arange(len(_TIPS))).repeat(1 + _K)])
_RADIUS_OF_POINT = np.asarray(hs.CAPSULE_RADII_M, np.float32)[hs.SURFACE_CAPSULE]
# Each capsule's surface points, padded to the longest by repeating its first (a repeat changes no min or max).
_CAP_POINTS = np.stack([np.pad(np.flatnonzero(hs.SURFACE_CAPSULE == c),
                               (0, np.bincount(hs.SURFACE_CAPSULE).max() - (hs.SURFACE_CAPSULE == c).sum()), "edge")
                        for c in range(_C)])


def _coarse_frame(obj, state_7, joints_2x21x3):
    """Per part, hand and surface point the lower bound sdf(centre) - r (2, 2, P), and the points (2, P, 3)."""
    pts, _ = hs.surface_points(joints_2x21x3)                                        # (2, P, 3)
    p, q = hs.capsules(joints_2x21x3)                                                # (2, C, 3)
    centres = jnp.concatenate([(p[:, :, None] + jnp.asarray(hs.RINGS, jnp.float32)[:, None] * (q - p)[:, :, None])
                               .reshape(2, -1, 3), q[:, _TIPS]], 1)                  # (2, C * R + 5, 3)
    _, per_part = object_sdf(obj, state_7, centres.reshape(-1, 3))
    bound = per_part.reshape(2, 2, -1)[:, :, _CENTRE_OF_POINT] - _RADIUS_OF_POINT      # (part, hand, P)
    return bound, pts


@jax.jit
def _coarse(objs, states_NxTx7, joints_NxTx2x21x3):
    bound, pts = jax.vmap(jax.vmap(_coarse_frame, (None, 0, 0)), (0, 0, 0))(objs, states_NxTx7, joints_NxTx2x21x3)
    N, T = states_NxTx7.shape[:2]
    inter = hs.interhand_signed_distance(joints_NxTx2x21x3.reshape(N * T, 2, 21, 3)).reshape(N, T)
    return bound, pts, inter


@jax.jit
def _exact(objs, states_NxTx7, pts_NxTx2xPx3, n_B, t_B, h_B, c_B):
    """The exact per-part SDF (B, 2, Q) of the points of capsule c_B of hand h_B on frame t_B of clip n_B."""
    def row(n, t, h, c):
        obj = jax.tree.map(lambda a: a[n], objs)
        return object_sdf(obj, states_NxTx7[n, t], pts_NxTx2xPx3[n, t, h][jnp.asarray(_CAP_POINTS)[c]])[1]
    return jax.vmap(row)(n_B, t_B, h_B, c_B)


# The exact pass runs in blocks of this many rows (one compiled shape for every chunk; the last block is padded).
EXACT_BLOCK = 4096


def measure(objs, states_NxTx7, joints_NxTx2x21x3) -> dict[str, np.ndarray]:
    """Per frame: ``depth`` (N, T, 2) m, ``near_part`` (N, T, 2 hands, 2 parts) each hand's least signed distance
    to each part, ``pad`` (N, T, 2, 5), ``interhand`` (N, T). Distances beyond NEAR_M are lower bounds."""
    states = jnp.asarray(states_NxTx7, jnp.float32)
    bound, pts, inter = _coarse(objs, states, jnp.asarray(joints_NxTx2x21x3, jnp.float32))
    d = np.array(bound, np.float32).transpose(0, 1, 3, 2, 4)                         # (N, T, hand, part, P)
    N, T = d.shape[:2]
    cap = _capsule_min(d.min(3))                                                     # (N, T, hand, C)
    n, t, h, c = np.nonzero(cap <= NEAR_M)
    B = len(n)
    size = -(-B // EXACT_BLOCK) * EXACT_BLOCK
    idx = np.stack([np.pad(a, (0, size - B)) for a in (n, t, h, c)]).astype(np.int32)
    exact = np.concatenate([np.asarray(_exact(objs, states, pts, *map(jnp.asarray, idx[:, k:k + EXACT_BLOCK])))
                            for k in range(0, size, EXACT_BLOCK)] or [np.zeros((0, 2, _CAP_POINTS.shape[1]))])
    d[n[:, None], t[:, None], h[:, None], :, _CAP_POINTS[c]] = exact[:B].transpose(0, 2, 1)
    d = d.astype(np.float64)
    dmin = d.min(3)                                                                  # (N, T, hand, P)
    pad = np.stack([dmin[..., p].min(-1) for p in PAD_POINTS], -1)                   # (N, T, hand, 5)
    pad_part = np.stack([d[..., p].min(-1) for p in PAD_POINTS], -1)                 # (N, T, hand, part, 5)
    return {"depth": np.maximum(-dmin.min(-1), 0.0), "near_part": d.min(-1), "pad": pad, "pad_part": pad_part,
            "interhand": np.asarray(inter, np.float64)}


def pad_on_held_part(m: dict, parts_Nx2: np.ndarray) -> np.ndarray:
    """Each pad's distance (N, T, 2, 5) to the part its hand holds (``parts_Nx2``: objects.TOP / BOTTOM), not to
    the nearer part: a pad resting on the other part does not hold this one (in a use clip the two part ways)."""
    p = np.asarray(parts_Nx2)[:, None, :, None, None]
    return np.take_along_axis(m["pad_part"], np.broadcast_to(p, m["pad_part"].shape[:3] + (1, 5)), 3)[:, :, :, 0]


def _capsule_min(d_xP: np.ndarray) -> np.ndarray:
    """Per capsule the least value over its surface points: (..., C)."""
    return np.stack([d_xP[..., _CAP_POINTS[c]].min(-1) for c in range(_C)], -1)


def drift(joints_in_part_NxTx2x21x3: np.ndarray, held_NxTx2: np.ndarray) -> np.ndarray:
    """(N, 2): the largest distance any joint of a holding hand moves, in its held part's frame, from its place at
    the first held frame (0 for a hand that does not hold)."""
    J = np.asarray(joints_in_part_NxTx2x21x3, np.float64)
    held = np.asarray(held_NxTx2) >= 0
    first = np.argmax(held, axis=1)                                                  # (N, 2)
    ref = np.take_along_axis(J, first[:, None, :, None, None], 1)
    d = np.linalg.norm(J - ref, axis=-1).max(-1)                                     # (N, T, 2)
    return np.where(held, d, 0.0).max(1)


def joints_in_part(states_NxTx7, joints_NxTx2x21x3, held_NxTx2) -> np.ndarray:
    """Each hand's joints in the frame of the part it holds during the clip (its first held part; BOTTOM where it
    holds none), (N, T, 2, 21, 3), float64."""
    from handx_jax.synthesis.object_motion import part_poses

    held = np.asarray(held_NxTx2)
    part = np.where((held >= 0).any(1), np.take_along_axis(held, np.argmax(held >= 0, 1)[:, None], 1)[:, 0], 1)
    R, t = part_poses(states_NxTx7)                                                   # (N, T, 2, ...)
    R = np.take_along_axis(R, part[:, None, :, None, None], 2)
    t = np.take_along_axis(t, part[:, None, :, None], 2)
    return np.einsum("nthkj,nthji->nthki", np.asarray(joints_NxTx2x21x3, np.float64) - t[:, :, :, None], R)


@jax.jit
def _contact_maps(objs, bps_Nx2xKx3, states_NxTx7, joints_NxTx2x21x3):
    def frame(obj, bps, s, j):
        pts = jnp.concatenate([to_world(obj, p, s, bps[p]) for p in range(2)])       # (2K, 3)
        return hs.hand_sdf(jnp.broadcast_to(pts, (2,) + pts.shape), j)              # (2 hands, 2K)
    return jax.vmap(jax.vmap(frame, (None, None, 0, 0)), (0, 0, 0, 0))(objs, bps_Nx2xKx3, states_NxTx7,
                                                                         joints_NxTx2x21x3)


def contact_maps(objs, bps_Nx2xKx3, states_NxTx7, joints_NxTx2x21x3) -> np.ndarray:
    """(N, T, 2 hands, 2 parts, K): distance (m) from each part's basis-mapped point to each hand's surface (< 0:
    inside the hand), BimArt §3.2."""
    N, T = states_NxTx7.shape[:2]
    K = bps_Nx2xKx3.shape[2]
    out = _contact_maps(objs, jnp.asarray(bps_Nx2xKx3, jnp.float32), jnp.asarray(states_NxTx7, jnp.float32),
                        jnp.asarray(joints_NxTx2x21x3, jnp.float32))
    return np.asarray(out, np.float32).reshape(N, T, 2, 2, K)


def verdict(m: dict, drift_Nx2: np.ndarray, held_NxTx2: np.ndarray, contact_Nx2x5: np.ndarray) -> dict[str, np.ndarray]:
    """Per clip and limit, whether it holds (N,) bool each; the pads checked are the contact fingers' while held."""
    held = np.asarray(held_NxTx2) >= 0
    pad = np.where(held[..., None] & contact_Nx2x5[:, None], np.abs(m["pad"]), 0.0).max((1, 2, 3))
    return {"depth": m["depth"].max((1, 2)) <= LIMITS["depth_m"],
            "interhand": m["interhand"].min(1) > -LIMITS["interhand_m"],
            "pad": pad <= LIMITS["pad_m"],
            "drift": drift_Nx2.max(1) < LIMITS["drift_m"]}
