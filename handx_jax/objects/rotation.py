"""Axis-angle (rotation vector) rotations, differentiable at the identity.

ARCTIC stores an object's global rotation as an axis-angle 3-vector (its ``.object.npy`` columns 1:4) and
articulates the top part about the canonical -z axis (BimArt App. B), so both go through here.
"""

import jax.numpy as jnp

# Below this squared angle the Taylor series of sin(t)/t and (1-cos t)/t^2 replace the closed forms, so the
# value and the gradient stay finite at the identity (the closed forms divide 0 by 0 there).
_SMALL_THETA2 = 1e-8


def skew(v_x3):
    """The cross-product matrix [v]_x, (..., 3, 3)."""
    z = jnp.zeros_like(v_x3[..., 0])
    x, y, w = v_x3[..., 0], v_x3[..., 1], v_x3[..., 2]
    return jnp.stack([jnp.stack([z, -w, y], -1), jnp.stack([w, z, -x], -1), jnp.stack([-y, x, z], -1)], -2)


def rotvec_to_matrix(rotvec_x3):
    """Rodrigues' formula R = I + a K + b K^2 with K = [r]_x, a = sin t / t, b = (1 - cos t) / t^2, t = |r|."""
    t2 = jnp.sum(rotvec_x3 * rotvec_x3, axis=-1)
    small = t2 < _SMALL_THETA2
    t = jnp.sqrt(jnp.where(small, 1.0, t2))
    a = jnp.where(small, 1.0 - t2 / 6.0, jnp.sin(t) / t)
    b = jnp.where(small, 0.5 - t2 / 24.0, (1.0 - jnp.cos(t)) / jnp.where(small, 1.0, t2))
    K = skew(rotvec_x3)
    eye = jnp.eye(3, dtype=rotvec_x3.dtype)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def hinge_matrix(angle):
    """The top part's articulation: rotation by ``angle`` about the canonical -z axis (ARCTIC's
    ``object_tensors``: ``z_axis = [0, 0, -1]``, rotvec = z_axis * angle). (..., 3, 3)."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    z, o = jnp.zeros_like(angle), jnp.ones_like(angle)
    # R(-z, a) = R(z, -a): x -> (c, -s, 0), y -> (s, c, 0).
    return jnp.stack([jnp.stack([c, s, z], -1), jnp.stack([-s, c, z], -1), jnp.stack([z, z, o], -1)], -2)
