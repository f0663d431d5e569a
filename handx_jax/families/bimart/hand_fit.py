"""The parametric hand BimArt's refinement fits and optimises (§3.4, Eq. 8), without MANO.

BimArt fits MANO Θ = [θ | β] to the denoised keypoints Ĥ (Eq. 8), then refines Θ (Eq. 9): the hand that comes
out is always a hand — bones of one length over the clip, joints that bend only where joints bend. This project's
hand is the procedural corpus's forward kinematics (synthesis/hand.py: 16 joint angles, the left hand the right
one mirrored in x), so its Θ is, per hand:

- β: the bone geometry of the whole clip — an overall scale and a relative length per finger bone (5 × 3), the
  arguments of ``hand.hand_geometry``; fitted in Eq. 8, frozen in Eq. 9 (MANO's β is one per sequence too);
- θ per frame: the wrist's rotation (6D, Zhou et al.'s continuous form), its translation, and the 16 angles,
  each squashed into its joint limits by a sigmoid so no optimiser step can leave the hand's range of motion.

``init`` starts Θ in closed form from predicted joints: per frame a similarity (Umeyama) alignment of the rest
hand's rigid palm (wrist, thumb CMC, four MCPs: they do not move with any angle) to the predicted palm gives the
rotation, translation and scale; angles start mid-range. Everything is traceable (jit, vmap, grad).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax

from handx_jax import skeleton as sk
from handx_jax.synthesis import hand as H

_LO = np.asarray(H.LIMITS_LO_16, np.float32)
_HI = np.asarray(H.LIMITS_HI_16, np.float32)
# x → −x for the left hand (hand index sk.LEFT), applied in the hand's own frame before the wrist's pose.
_MIRROR_2x3 = np.ones((2, 3), np.float32)
_MIRROR_2x3[sk.LEFT, 0] = -1.0
# The rigid palm: joints whose positions in the hand frame depend on the geometry only.
PALM = np.asarray((0,) + sk.BASES, np.int32)
# Metres per unit of each parameter's Adam step (Adam normalises each gradient to about one unit): the wrist
# moves ~1 mm, an angle's logit ~0.05 (~2° mid-range), a 6D rotation ~0.01 rad, the geometry ~0.5%.
STEP_SCALE = {"trans": 1e-3, "rot6": 1e-2, "pose": 5e-2, "scale": 5e-3, "jitter": 5e-3}


def geometry(scale_2, jitter_2x5x3) -> dict:
    """``hand.hand_geometry`` in JAX (float32): bone vectors of both hands, each (2, ...)."""
    s = scale_2[:, None]
    j = 1.0 + jitter_2x5x3
    return {"mcp_Nx4x3": 0.01 * s[:, :, None] * jnp.asarray(H._FINGER_MCP_CM_4x3, jnp.float32),
            "bones_Nx4x3": 0.01 * s[:, :, None] * jnp.asarray(H._FINGER_BONES_CM_4x3, jnp.float32) * j[:, 1:],
            "cmc_Nx3": 0.01 * s * jnp.asarray(H._THUMB_CMC_CM_3, jnp.float32),
            "thumb_bones_Nx3": 0.01 * s * jnp.asarray(H._THUMB_BONES_CM_3, jnp.float32) * j[:, 0]}


def rot6_to_matrix(d6):
    """(..., 6) → (..., 3, 3), rows a, b, a × b after Gram-Schmidt (the columns are the hand frame's axes)."""
    a = d6[..., :3] / jnp.linalg.norm(d6[..., :3], axis=-1, keepdims=True)
    b = d6[..., 3:] - jnp.sum(a * d6[..., 3:], -1, keepdims=True) * a
    b = b / jnp.linalg.norm(b, axis=-1, keepdims=True)
    return jnp.stack([a, b, jnp.cross(a, b)], -2)


def angles(params):
    """The 16 joint angles (T, 2, 16), degrees, within the limits."""
    return _LO + (_HI - _LO) * jax.nn.sigmoid(params["pose"])


def joints(params):
    """Θ → world joints (T, 2, 21, 3), metres."""
    g = geometry(params["scale"], params["jitter"])
    local = H.hand_fk(angles(params), g, xp=jnp) * _MIRROR_2x3[:, None]          # (T, 2, 21, 3)
    R = rot6_to_matrix(params["rot6"])                                           # (T, 2, 3, 3)
    return jnp.einsum("thij,thkj->thki", R, local) + params["trans"][:, :, None]


def _similarity(src_Nx3, dst_Nx3):
    """Umeyama: s, R, t minimising Σ‖s R src + t − dst‖² (R proper)."""
    ms, md = src_Nx3.mean(0), dst_Nx3.mean(0)
    a, b = src_Nx3 - ms, dst_Nx3 - md
    U, S, Vt = jnp.linalg.svd(b.T @ a)
    d = jnp.sign(jnp.linalg.det(U @ Vt))
    D = jnp.array([1.0, 1.0, 0.0]) + d * jnp.array([0.0, 0.0, 1.0])
    R = (U * D) @ Vt
    s = jnp.sum(S * D) / jnp.maximum(jnp.sum(a * a), 1e-12)
    return s, R, md - s * R @ ms


def init(joints_Tx2x21x3):
    """Θ from predicted joints: per frame the palm's similarity to the rest hand (scale 1) gives R and t; the
    clip's scale is the median over frames; the angles start mid-range, bone lengths at the rest hand's."""
    T = joints_Tx2x21x3.shape[0]
    rest = H.hand_fk(jnp.zeros((2, 16), jnp.float32),
                     geometry(jnp.ones((2,)), jnp.zeros((2, 5, 3))), xp=jnp) * _MIRROR_2x3[:, None]  # (2, 21, 3)
    src = rest[:, PALM]                                                                             # (2, 6, 3)
    dst = joints_Tx2x21x3[:, :, PALM]                                                               # (T, 2, 6, 3)
    s, R, t = jax.vmap(jax.vmap(_similarity), (None, 0))(src, dst)                                  # (T, 2), ...
    scale = jnp.clip(jnp.median(s, axis=0), 0.6, 1.6)
    # With the clip's scale, the translation that puts the palm's centroid where the prediction has it.
    t = dst.mean(-2) - scale[None, :, None] * jnp.einsum("thij,hj->thi", R, src.mean(-2))
    return {"rot6": jnp.concatenate([R[..., 0, :], R[..., 1, :]], -1),  # rows: rot6_to_matrix's convention
            "trans": t, "pose": jnp.zeros((T, 2, 16), jnp.float32),
            "scale": scale.astype(jnp.float32), "jitter": jnp.zeros((2, 5, 3), jnp.float32)}


def scaled_adam_step(opt_state, params, grads, step_scale, frozen=()):
    """One Adam step of unit learning rate, scaled per parameter (``step_scale``: a dict like ``STEP_SCALE``, or
    one number for every leaf); ``frozen`` keys of a dict stay where they are."""
    upd, opt_state = optax.scale_by_adam().update(grads, opt_state, params)
    if not isinstance(params, dict):
        return params - step_scale * upd, opt_state
    return {k: params[k] if k in frozen else params[k] - step_scale[k] * upd[k] for k in params}, opt_state


def adam_init(params):
    return optax.scale_by_adam().init(params)
