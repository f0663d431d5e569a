"""The diffusion family's motion layout (reference §1.8, §2.3): ``(T, 42, 4)``, centred xyz and the rotation
scalar per joint, its inverse, and its normalisation (``DIFFUSION_NORM``, the registry's ``Family.norm``)."""

from __future__ import annotations

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.representation.geometry import Convention, check_trailing, out_dtype, rotation_scalar
from handx_jax.representation.norm import NormPreset


DIFFUSION_SHAPE = (2 * sk.NUM_JOINTS, 4)


def diffusion_center(joints_xTx2x21x3: np.ndarray) -> np.ndarray:
    """Per-clip centre (§1.8): mean over t of the wrist midpoint, shape ``(..., 3)`` (float64)."""
    p = np.asarray(joints_xTx2x21x3)
    check_trailing(p, (2, sk.NUM_JOINTS, 3), "diffusion_center", min_ndim=1)
    p = p.astype(np.float64, copy=False)
    return 0.5 * (p[..., sk.LEFT, 0, :] + p[..., sk.RIGHT, 0, :]).mean(axis=-2)


def to_diffusion(joints_xTx2x21x3: np.ndarray, convention: Convention = "paper") -> np.ndarray:
    """Diffusion features ``(..., T, 42, 4)``: centred xyz (§1.8) and the rotation scalar (§2.3).

    Rows 0–20 are the left hand. The centre subtracted is :func:`diffusion_center`; pass it to
    :func:`diffusion_to_joints` to restore absolute positions.
    """
    p = np.asarray(joints_xTx2x21x3)
    check_trailing(p, (2, sk.NUM_JOINTS, 3), "to_diffusion", min_ndim=1)
    dt = out_dtype(p)
    p = p.astype(np.float64, copy=False)
    c = diffusion_center(p)
    xyz = p - c[..., None, None, None, :]
    s = rotation_scalar(p, convention).astype(np.float64)
    x = np.concatenate([xyz, s[..., None]], axis=-1)
    return x.reshape(*p.shape[:-3], *DIFFUSION_SHAPE).astype(dt, copy=False)


def diffusion_to_joints(x_xTx42x4: np.ndarray, center_x3: np.ndarray | None = None) -> np.ndarray:
    """Inverse of :func:`to_diffusion` (drops the scalar): ``(..., T, 2, 21, 3)``.

    Without ``center`` the joints stay in the clip-centred frame.
    """
    x = np.asarray(x_xTx42x4)
    check_trailing(x, DIFFUSION_SHAPE, "diffusion_to_joints", min_ndim=1)
    dt = out_dtype(x)
    j = x[..., :3].reshape(*x.shape[:-2], 2, sk.NUM_JOINTS, 3)
    if center_x3 is None:
        return j.astype(dt, copy=True)
    c = np.asarray(center_x3, dtype=np.float64)
    return (j.astype(np.float64) + c[..., None, None, None, :]).astype(dt, copy=False)


# The normalisation of each representation. §1.8: per (joint, channel), std < 1e-4 → 1, no eps.
DIFFUSION_NORM = NormPreset("diffusion", DIFFUSION_SHAPE, min_std=1e-4, featurize=to_diffusion)
