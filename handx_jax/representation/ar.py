"""The AR family's motion layout (reference §2.4, §9.2): 288 values per frame (root velocity, the left-right
wrist offset, 6D wrist rotations, rotation scalars, local positions and their velocities), its exact
inverse, and its normalisation (``AR_NORM``, the tokenizer's ``Family.norm``).

AR rotations. The official AR features take R_h from the fitted MANO global orient (§2.4). The procedural
corpus has no MANO fits, so by default R_h is the wrist frame of §2.1 (``geometry.wrist_frames``); ``to_ar``
accepts external rotations (e.g. MANO global orient as matrices) through ``rotations=``. The inverse
``ar_to_joints`` only needs the rotations stored in the features, so it is exact for either choice.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from handx_jax import skeleton as sk
from handx_jax.representation.geometry import (Convention, check_trailing, local_positions, out_dtype, rotation_scalar,
                                               unit_vectors, wrist_frames)
from handx_jax.representation.norm import NormPreset


@dataclass(frozen=True)
class ARLayout:
    """Slices of the 288-d AR frame vector, in the official code's order (reference §2.4, §9.2)."""

    # right-wrist velocity p[t+1] − p[t] in m/frame (not × fps); last frame 0
    root_vel: slice = field(default_factory=lambda: slice(0, 3))
    # left wrist − right wrist (the code's sign; the paper says "left→right")
    lr_offset: slice = field(default_factory=lambda: slice(3, 6))
    # 6D rotations: first two ROWS of R_left, then of R_right (PyTorch3D convention)
    rot6d: slice = field(default_factory=lambda: slice(6, 18))
    # rotation scalar of joints 1..15, left 15 then right 15
    scalar: slice = field(default_factory=lambda: slice(18, 48))
    # local positions R_hᵀ(p_j − p_wrist) of joints 1..20, order (hand, joint, xyz)
    local_pos: slice = field(default_factory=lambda: slice(48, 168))
    # forward difference of local_pos over frames; last frame 0
    local_vel: slice = field(default_factory=lambda: slice(168, 288))
    dim: int = 288


AR_LAYOUT = ARLayout()
AR_DIM = AR_LAYOUT.dim


def matrix_to_rotation_6d(R_x3x3: np.ndarray) -> np.ndarray:
    """6D rotation = first two rows of R, flattened (PyTorch3D convention), ``(..., 6)``."""
    R = np.asarray(R_x3x3)
    check_trailing(R, (3, 3), "matrix_to_rotation_6d")
    return R[..., :2, :].reshape(*R.shape[:-2], 6)


def rotation_6d_to_matrix(d6_x6: np.ndarray) -> np.ndarray:
    """Gram–Schmidt 6D → rotation (§2.4 inverse, PyTorch3D): rows b1 = n(a1), b2 = n(a2 − (b1·a2)b1), b3 = b1×b2."""
    d6 = np.asarray(d6_x6)
    check_trailing(d6, (6,), "rotation_6d_to_matrix")
    dt = out_dtype(d6)
    d6 = d6.astype(np.float64, copy=False)
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1, _ = unit_vectors(a1, floor=1e-12)
    b2, _ = unit_vectors(a2 - np.sum(b1 * a2, -1, keepdims=True) * b1, floor=1e-12)
    b3 = np.cross(b1, b2)
    return np.stack([b1, b2, b3], axis=-2).astype(dt, copy=False)


def _forward_diff_last0(x_xTxD: np.ndarray) -> np.ndarray:
    d = np.zeros_like(x_xTxD)
    d[..., :-1, :] = x_xTxD[..., 1:, :] - x_xTxD[..., :-1, :]
    return d


def to_ar(joints_xTx2x21x3: np.ndarray, *, rotations_xTx2x3x3: np.ndarray | None = None,
          convention: Convention = "paper") -> np.ndarray:
    """AR features ``(..., T, 288)`` in the layout of :data:`AR_LAYOUT` (reference §2.4).

    ``joints`` are raw (not centred) positions. ``rotations`` (columns = local axes, i.e. MANO global
    orient as a matrix) default to :func:`wrist_frames` because the procedural corpus has no MANO fits.
    ``convention`` selects the rotation scalar stored in slots 18:48 (it is not used by the inverse).
    """
    p = np.asarray(joints_xTx2x21x3)
    check_trailing(p, (2, sk.NUM_JOINTS, 3), "to_ar", min_ndim=1)
    dt = out_dtype(p)
    p = p.astype(np.float64, copy=False)
    lead = p.shape[:-3]  # (..., T)
    if rotations_xTx2x3x3 is None:
        R = wrist_frames(p)
    else:
        R = np.asarray(rotations_xTx2x3x3, dtype=np.float64)
        if R.shape != (*lead, 2, 3, 3):
            raise ValueError(f"to_ar: rotations must have shape {(*lead, 2, 3, 3)}, got {R.shape}")
    right_wrist, left_wrist = p[..., sk.RIGHT, 0, :], p[..., sk.LEFT, 0, :]
    root_vel = _forward_diff_last0(right_wrist)
    lr_offset = left_wrist - right_wrist
    rot6d = matrix_to_rotation_6d(R).reshape(*lead, 12)
    scal = rotation_scalar(p, convention).astype(np.float64)[..., 1:16].reshape(*lead, 30)
    loc = local_positions(p, R)[..., 1:, :].reshape(*lead, 120)
    loc_vel = _forward_diff_last0(loc)
    f = np.concatenate([root_vel, lr_offset, rot6d, scal, loc, loc_vel], axis=-1)
    return f.astype(dt, copy=False)


def ar_to_joints(f_xTx288: np.ndarray, root0_x3: np.ndarray | None = None) -> np.ndarray:
    """Exact inverse of :func:`to_ar` (reference §2.4 inverse): ``(..., T, 2, 21, 3)``.

    R_h from the stored 6D (Gram–Schmidt); p_j = root_h + R_h · local_j; right wrist
    root_R(t) = root0 + Σ_{s<t} vel(s) (root0 = frame-0 right wrist, default the origin as in the
    released clips, §1.7); left wrist = right wrist + offset. Accumulation is in float64.
    """
    f = np.asarray(f_xTx288)
    check_trailing(f, (AR_DIM,), "ar_to_joints", min_ndim=1)
    dt = out_dtype(f)
    f = f.astype(np.float64, copy=False)
    L = AR_LAYOUT
    lead = f.shape[:-1]  # (..., T)
    R = rotation_6d_to_matrix(f[..., L.rot6d].reshape(*lead, 2, 6)).astype(np.float64)  # (..., T, 2, 3, 3)
    loc = f[..., L.local_pos].reshape(*lead, 2, sk.NUM_JOINTS - 1, 3)
    rel = np.einsum("...hij,...hkj->...hki", R, loc)
    vel = f[..., L.root_vel]
    root_r = np.zeros_like(vel)
    root_r[..., 1:, :] = np.cumsum(vel[..., :-1, :], axis=-2)
    if root0_x3 is not None:
        root_r = root_r + np.asarray(root0_x3, dtype=np.float64)[..., None, :]
    root_l = root_r + f[..., L.lr_offset]
    roots = np.stack([root_l, root_r], axis=-2)[..., None, :]  # (..., T, 2, 1, 3)
    return np.concatenate([roots, roots + rel], axis=-2).astype(dt, copy=False)


# §1.8: per 288-d feature, std < 1e-6 → 1, loaders add 1e-6.
AR_NORM = NormPreset("ar", (AR_DIM,), min_std=1e-6, eps=1e-6,
                     featurize=lambda j, convention="paper": to_ar(j, convention=convention))
