"""G-HTT's per-frame hand representation (App. B.2) and its exact inverse, in JAX.

Each frame of a bimanual clip becomes ``H = (p^L, p^R, v^L, v^R, r)``, 153 values for HandX's 21 joints
(the paper's 147 are for 20 joints, 6N + 27):

- ``p`` (63 per hand): the joints in the hand's palm frame, divided by the hand's size (the mean length
  of its four wrist→MCP palm bones over the clip: the paper's "average length of palm bones", Eq. 6);
- ``v`` (9 per hand): the palm's rigid motion since the previous frame, 6D rotation [65] + translation;
  identity at a clip's (or observation's) first frame (Eq. 7);
- ``r`` (9): the right palm's pose in the left palm's frame in the same frame.

The palm frame ``G = (R, o)`` (local → global) has its origin at the wrist, x towards the middle MCP,
z normal to the palm (x × (index MCP − pinky MCP)), y = z × x. Where the paper writes
``v_i = a_i⁻¹ ∘ a_{i−1}`` (a global-frame displacement), ``v`` here is the displacement in the previous
palm frame, ``G_{i−1}⁻¹ ∘ G_i``, and ``r = G^L⁻¹ ∘ G^R``: both unchanged by a rigid motion of the whole
clip, so the model never sees where in the room the hands are, only how they move (HandX clips are in a
canonical frame, but prediction continues from wherever the observation ends).

The inverse (Eqs. 8–9) accumulates ``v`` from a given anchor palm frame (the frame before the first
frame, or the first frame itself) and scales ``p`` back: exact up to float rounding given the anchor and
the hand sizes (``tests/test_ghtt.py``: < 1e-4 m on real clips over 60 frames).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

WRIST, INDEX_MCP, MIDDLE_MCP, PINKY_MCP, RING_MCP = 0, 1, 4, 7, 10
PALM_BONES = (INDEX_MCP, MIDDLE_MCP, RING_MCP, PINKY_MCP)
J = 21
P_DIM, RIGID = 3 * J, 9
FRAME_DIM = 2 * P_DIM + 3 * RIGID  # 153 = 6N + 27 (App. B.3, MLP1's output width)
# Slices of a frame's 153 values: the parts Eq. 11 embeds separately.
P_SLICE, V_SLICE, R_SLICE = slice(0, 2 * P_DIM), slice(2 * P_DIM, 2 * P_DIM + 2 * RIGID), slice(2 * P_DIM + 2 * RIGID, FRAME_DIM)


def _unit(x, eps=1e-9):
    return x / jnp.sqrt(jnp.sum(x * x, -1, keepdims=True) + eps)


def palm_frames(joints_Tx2x21x3):
    """Each hand's palm frame per frame: rotation (T, 2, 3, 3) (columns = local axes in global) and
    origin (T, 2, 3)."""
    h = joints_Tx2x21x3
    o = h[..., WRIST, :]
    x = _unit(h[..., MIDDLE_MCP, :] - o)
    z = _unit(jnp.cross(x, h[..., INDEX_MCP, :] - h[..., PINKY_MCP, :]))
    y = jnp.cross(z, x)
    return jnp.stack([x, y, z], -1), o


def hand_scale(joints_Tx2x21x3):
    """Per hand, the mean wrist→MCP palm-bone length over the frames (2,): the size p is divided by."""
    h = joints_Tx2x21x3
    bones = jnp.linalg.norm(h[..., PALM_BONES, :] - h[..., WRIST:WRIST + 1, :], axis=-1)  # (T, 2, 4)
    return bones.mean((0, 2))


def rot_to_6d(R_x3x3):
    """The 6D rotation of [65]: the first two columns, (…, 6)."""
    return jnp.concatenate([R_x3x3[..., :, 0], R_x3x3[..., :, 1]], -1)


def rot_from_6d(d6):
    """Gram–Schmidt of the two columns back to a rotation (…, 3, 3)."""
    a = _unit(d6[..., :3])
    b = _unit(d6[..., 3:6] - jnp.sum(a * d6[..., 3:6], -1, keepdims=True) * a)
    return jnp.stack([a, b, jnp.cross(a, b)], -1)


def rigid_9d(R, t):
    return jnp.concatenate([rot_to_6d(R), t], -1)


def rel(Ra, oa, Rb, ob):
    """``A⁻¹ ∘ B`` for frames A = (Ra, oa), B = (Rb, ob): B expressed in A."""
    RaT = jnp.swapaxes(Ra, -1, -2)
    return RaT @ Rb, jnp.einsum("...ij,...j->...i", RaT, ob - oa)


def compose(Ra, oa, Rb, tb):
    """``A ∘ B``: a frame B given in A, placed in A's parent."""
    return Ra @ Rb, oa + jnp.einsum("...ij,...j->...i", Ra, tb)


def to_frames(joints_Tx2x21x3, scale_2=None):
    """Joints (T, 2, 21, 3) → H (T, 153), with the palm frames (R (T, 2, 3, 3), o (T, 2, 3)) and the
    hand sizes (2,) the inverse needs. ``v`` of frame 0 is the identity (no previous frame)."""
    h = jnp.asarray(joints_Tx2x21x3, jnp.float32)
    T = h.shape[0]
    R, o = palm_frames(h)
    s = hand_scale(h) if scale_2 is None else jnp.asarray(scale_2, jnp.float32)
    RT = jnp.swapaxes(R, -1, -2)
    p = jnp.einsum("thij,thkj->thki", RT, h - o[:, :, None, :]) / s[None, :, None, None]  # Eq. 6
    Rv, tv = rel(R[:-1], o[:-1], R[1:], o[1:])  # Eq. 7, in the previous palm frame
    eye = jnp.broadcast_to(jnp.eye(3), (1, 2, 3, 3))
    v = rigid_9d(jnp.concatenate([eye, Rv]), jnp.concatenate([jnp.zeros((1, 2, 3)), tv]))  # (T, 2, 9)
    Rr, tr = rel(R[:, 0], o[:, 0], R[:, 1], o[:, 1])
    r = rigid_9d(Rr, tr)  # (T, 9)
    H = jnp.concatenate([p.reshape(T, 2 * P_DIM), v.reshape(T, 2 * RIGID), r], -1)
    return H, (R, o), s


def accumulate(v_Tx2x9, R0_2x3x3, o0_2x3):
    """Palm frames after each frame's motion from the anchor (R0, o0) (Eq. 8): frame i is
    anchor ∘ v_1 ∘ … ∘ v_i; returns (R (T, 2, 3, 3), o (T, 2, 3))."""
    Rv, tv = rot_from_6d(v_Tx2x9[..., :6]), v_Tx2x9[..., 6:]

    def step(c, x):
        R, o = compose(c[0], c[1], x[0], x[1])
        return (R, o), (R, o)

    _, (R, o) = jax.lax.scan(step, (R0_2x3x3, o0_2x3), (Rv, tv))
    return R, o


def from_frames(H_Tx153, R0_2x3x3, o0_2x3, scale_2, *, first_is_anchor: bool = True):
    """H → joints (T, 2, 21, 3) (Eq. 9). ``first_is_anchor``: (R0, o0) is frame 0's palm frame and frame
    0's ``v`` is not used (the inverse of :func:`to_frames`); else (R0, o0) is the frame BEFORE frame 0
    (a predicted span continuing from the last observed frame)."""
    T = H_Tx153.shape[0]
    p = H_Tx153[:, P_SLICE].reshape(T, 2, J, 3)
    v = H_Tx153[:, V_SLICE].reshape(T, 2, RIGID)
    if first_is_anchor:
        v = v.at[0].set(rigid_9d(jnp.broadcast_to(jnp.eye(3), (2, 3, 3)), jnp.zeros((2, 3))))
    R, o = accumulate(v, R0_2x3x3, o0_2x3)
    return o[:, :, None, :] + jnp.einsum("thij,thkj->thki", R, p * scale_2[None, :, None, None])


def trajectory(v_BxTx2x9):
    """Eq. 8's accumulated palm poses s_i (relative to the frame before the span), as 9-D (6D + translation)
    per hand: (B, T, 2, 9). Differentiable; the trajectory loss (Eq. 2) compares them."""
    B = v_BxTx2x9.shape[0]
    eye = jnp.broadcast_to(jnp.eye(3), (B, 2, 3, 3))
    R, o = jax.vmap(accumulate, (0, 0, 0))(v_BxTx2x9, eye, jnp.zeros((B, 2, 3)))
    return rigid_9d(R, o)


def axis_angle_rotation(axis_x3, angle):
    """Rodrigues: the rotation by ``angle`` about the unit ``axis`` (…, 3, 3)."""
    k = _unit(axis_x3)
    K = jnp.stack([jnp.stack([jnp.zeros_like(k[..., 0]), -k[..., 2], k[..., 1]], -1),
                   jnp.stack([k[..., 2], jnp.zeros_like(k[..., 0]), -k[..., 0]], -1),
                   jnp.stack([-k[..., 1], k[..., 0], jnp.zeros_like(k[..., 0])], -1)], -2)
    a = angle[..., None, None]
    return jnp.eye(3) + jnp.sin(a) * K + (1 - jnp.cos(a)) * (K @ K)
