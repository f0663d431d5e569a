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


def _frame(obj, state_7, joints_2x21x3):
    pts, _ = hs.surface_points(joints_2x21x3)                                       # (2, P, 3)
    _, per_part = object_sdf(obj, state_7, pts.reshape(-1, 3))                       # (2 parts, 2P)
    per_part = per_part.reshape(2, 2, -1)                                            # (part, hand, P)
    d = jnp.min(per_part, axis=0)                                                    # (hand, P)
    pad = jax.ops.segment_min(d[:, _PAD_CAT].T, _PAD_SEG, num_segments=5).T          # (hand, 5)
    return {"depth": jnp.maximum(-jnp.min(d, -1), 0.0), "near_part": jnp.min(per_part, -1).T, "pad": pad}


@jax.jit
def _measure(objs, states_NxTx7, joints_NxTx2x21x3):
    per_clip = jax.vmap(jax.vmap(_frame, (None, 0, 0)), (0, 0, 0))(objs, states_NxTx7, joints_NxTx2x21x3)
    N, T = states_NxTx7.shape[:2]
    per_clip["interhand"] = hs.interhand_signed_distance(joints_NxTx2x21x3.reshape(N * T, 2, 21, 3)).reshape(N, T)
    return per_clip


def measure(objs, states_NxTx7, joints_NxTx2x21x3) -> dict[str, np.ndarray]:
    """Per frame: ``depth`` (N, T, 2) m, ``near_part`` (N, T, 2 hands, 2 parts) each hand's least signed distance
    to each part, ``pad`` (N, T, 2, 5), ``interhand`` (N, T)."""
    out = _measure(objs, jnp.asarray(states_NxTx7, jnp.float32), jnp.asarray(joints_NxTx2x21x3, jnp.float32))
    return {k: np.asarray(v, np.float64) for k, v in out.items()}


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
