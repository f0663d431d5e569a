"""Motion representations: wrist frames, the rotation scalar, diffusion (T,42,4), AR 288-d, evaluator 126-d.

Everything here is NumPy, pure, and vectorised over any leading batch dimensions. Joints are laid out
``(..., 2, 21, 3)`` (hand 0 = left), sequences ``(..., T, 2, 21, 3)``. Geometry is computed in float64;
results come back as float64 for float64 input and float32 otherwise.

References (handx-reference.md):
- §2.1 wrist-anchored local frame, §2.2 rotation scalar (code) and paper App. C (paper), §9.1;
- §1.8 centring and normalisation, §2.3 diffusion layout;
- §2.4 AR 288-d layout and its inverse, §9.2;
- §5.3 evaluator preprocessing.

AR rotations. The official AR features take R_h from the fitted MANO global orient (§2.4). The procedural
corpus has no MANO fits, so by default R_h is the wrist frame of §2.1 (:func:`wrist_frames`); ``to_ar``
accepts external rotations (e.g. MANO global orient as matrices) through ``rotations=``. The inverse
``ar_to_joints`` only needs the rotations stored in the features, so it is exact for either choice.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator, Literal, Mapping

import numpy as np

from handx_jax import skeleton as sk

Convention = Literal["paper", "code"]
CONVENTIONS: tuple[str, ...] = ("paper", "code")

# Interior joints (15 per hand) as (predecessor, joint, successor) index arrays, §2.2.
_TRI_15x3 = np.asarray(sk.INTERIOR_TRIPLES, dtype=np.int64)
_WRIST, _INDEX_MCP, _MIDDLE_MCP, _PINKY_MCP = 0, 1, 4, 7
DEGENERATE_EPS = 1e-6  # metres for bone lengths, sin(angle) for the x̂ × ŷ₀ test


# ----------------------------------------------------------------------------------------------
# helpers

def _out_dtype(x: np.ndarray) -> np.dtype:
    return np.dtype(np.float64) if x.dtype == np.float64 else np.dtype(np.float32)


def _check_trailing(x: np.ndarray, trailing: tuple[int, ...], what: str, min_ndim: int = 0) -> None:
    n = len(trailing)
    if x.ndim < n + min_ndim or tuple(x.shape[x.ndim - n:]) != trailing:
        lead = "(..., T, " if min_ndim else "(..., "
        raise ValueError(
            f"{what}: expected shape {lead}{', '.join(map(str, trailing))}), got {tuple(x.shape)}"
        )


def _normalize(v: np.ndarray, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors along the last axis and the norms. ``floor`` clamps the divisor (F.normalize-style)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = v / (np.maximum(n, floor) if floor > 0 else n)
    return u, n[..., 0]


def _raise_degenerate(bad: np.ndarray, what: str) -> None:
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        *lead, hand = idx
        raise ValueError(
            f"degenerate wrist frame: {what} at batch/frame index {tuple(lead)}, "
            f"{sk.HAND_NAMES[hand]} hand ({int(bad.sum())} degenerate hand-frames in total)"
        )


# ----------------------------------------------------------------------------------------------
# §2.1 wrist frame

def wrist_frames(joints_x2x21x3: np.ndarray, *, eps: float = DEGENERATE_EPS) -> np.ndarray:
    """Wrist-anchored local frame per hand (reference §2.1), shape ``(..., 2, 3, 3)``.

    The COLUMNS of each matrix are the local axes: x̂ = n(middle MCP − wrist), ŷ₀ = n(index MCP − wrist),
    ẑ = n(x̂ × ŷ₀), ŷ = n(ẑ × x̂). Local coordinates of a point p are ``R.T @ (p − wrist)``.
    A zero-length x̂/ŷ₀ bone or parallel x̂, ŷ₀ (|x̂ × ŷ₀| ≤ eps) raises ValueError naming the first
    offending index. NaN input propagates (it is not reported as degenerate).
    """
    p = np.asarray(joints_x2x21x3)
    _check_trailing(p, (2, sk.NUM_JOINTS, 3), "wrist_frames")
    dt = _out_dtype(p)
    R, (nx, ny0, nz) = _frame_axes(p.astype(np.float64, copy=False))
    _raise_degenerate(nx <= eps, "wrist and middle MCP coincide")
    _raise_degenerate(ny0 <= eps, "wrist and index MCP coincide")
    _raise_degenerate(nz <= eps, "wrist→middle-MCP and wrist→index-MCP are parallel")
    return R.astype(dt, copy=False)


def _frame_axes(p: np.ndarray, floor: float = 0.0) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """§2.1 frames ``(..., 2, 3, 3)`` (columns x̂, ŷ, ẑ) in ``p``'s precision, and the norms of
    (middle MCP − wrist, index MCP − wrist, x̂ × ŷ₀) for the degeneracy checks. ``floor`` > 0 clamps
    the divisors, so degenerate hands give zero axes instead of NaN."""
    w = p[..., _WRIST, :]
    ex, nx = _normalize(p[..., _MIDDLE_MCP, :] - w, floor)
    ey0, ny0 = _normalize(p[..., _INDEX_MCP, :] - w, floor)
    ez, nz = _normalize(_cross(ex, ey0), floor)
    ey, _ = _normalize(_cross(ez, ex), floor)
    return np.stack([ex, ey, ez], axis=-1), (nx, ny0, nz)


def local_positions(joints_x2x21x3: np.ndarray, rotations_x2x3x3: np.ndarray | None = None) -> np.ndarray:
    """``R_hᵀ (p_j − p_wrist)`` for all 21 joints, shape ``(..., 2, 21, 3)`` (wrist row is 0).

    ``rotations`` defaults to :func:`wrist_frames` (columns = local axes), giving §2.1's ``local(p)``.
    """
    p = np.asarray(joints_x2x21x3)
    _check_trailing(p, (2, sk.NUM_JOINTS, 3), "local_positions")
    dt = _out_dtype(p)
    p = p.astype(np.float64, copy=False)
    R = wrist_frames(p) if rotations_x2x3x3 is None else np.asarray(rotations_x2x3x3, dtype=np.float64)
    _check_trailing(R, (2, 3, 3), "local_positions rotations")
    d = p - p[..., :1, :]
    return np.einsum("...hic,...hji->...hjc", R, d).astype(dt, copy=False)


# ----------------------------------------------------------------------------------------------
# §2.2 / App. C rotation scalar

def rotation_scalar(joints_x2x21x3: np.ndarray, convention: Convention = "paper", *,
                    eps: float = DEGENERATE_EPS) -> np.ndarray:
    """Per-joint rotation scalar in radians, shape ``(..., 2, 21)``; wrist (0) and tips (16–20) are 0.

    For each of the 15 interior joints j with predecessor a and successor b (``skeleton.INTERIOR_TRIPLES``),
    u = j − a and v = b − j.

    - ``"paper"`` (default, paper App. C): u and v are projected onto the plane perpendicular to the
      pinky-MCP→index-MCP vector of that hand and frame; the value is the magnitude of the angle between
      the projections, atan2(|u'×v'|, u'·v') ∈ [0, π] (0 for a straight finger). Identical for both hands.
    - ``"code"`` (reference §2.2, exactly): u, v in the §2.1 local frame, keeping (x, z);
      s = atan2(v_z, v_x) − atan2(u_z, u_x), not wrapped (range (−2π, 2π)); negated for the right hand;
      NaN/±inf → 0.
    """
    if convention not in CONVENTIONS:
        raise ValueError(f"unknown rotation-scalar convention {convention!r}; expected one of {CONVENTIONS}")
    p = np.asarray(joints_x2x21x3)
    _check_trailing(p, (2, sk.NUM_JOINTS, 3), "rotation_scalar")
    dt = _out_dtype(p)
    p = p.astype(np.float64, copy=False)
    u = p[..., _TRI_15x3[:, 1], :] - p[..., _TRI_15x3[:, 0], :]  # (..., 2, 15, 3)
    v = p[..., _TRI_15x3[:, 2], :] - p[..., _TRI_15x3[:, 1], :]
    if convention == "code":
        R = wrist_frames(p, eps=eps)
        ax, az = R[..., None, :, 0], R[..., None, :, 2]  # (..., 2, 1, 3)
        with np.errstate(invalid="ignore"):
            s = (np.arctan2(np.sum(v * az, -1), np.sum(v * ax, -1))
                 - np.arctan2(np.sum(u * az, -1), np.sum(u * ax, -1)))
        s[..., sk.RIGHT, :] *= -1.0
        s = np.nan_to_num(s, nan=0.0, posinf=0.0, neginf=0.0)
    else:
        n, nn = _normalize(p[..., _INDEX_MCP, :] - p[..., _PINKY_MCP, :])  # (..., 2, 3)
        _raise_degenerate(nn <= eps, "pinky MCP and index MCP coincide")
        n = n[..., None, :]
        up = u - np.sum(u * n, -1, keepdims=True) * n
        vp = v - np.sum(v * n, -1, keepdims=True) * n
        s = np.arctan2(np.linalg.norm(np.cross(up, vp), axis=-1), np.sum(up * vp, -1))
    out = np.zeros(p.shape[:-1], dtype=np.float64)
    out[..., _TRI_15x3[:, 1]] = s
    return out.astype(dt, copy=False)


# ----------------------------------------------------------------------------------------------
# §1.8 / §2.3 diffusion representation (T, 42, 4)

DIFFUSION_SHAPE = (2 * sk.NUM_JOINTS, 4)


def diffusion_center(joints_xTx2x21x3: np.ndarray) -> np.ndarray:
    """Per-clip centre (§1.8): mean over t of the wrist midpoint, shape ``(..., 3)`` (float64)."""
    p = np.asarray(joints_xTx2x21x3)
    _check_trailing(p, (2, sk.NUM_JOINTS, 3), "diffusion_center", min_ndim=1)
    p = p.astype(np.float64, copy=False)
    return 0.5 * (p[..., sk.LEFT, 0, :] + p[..., sk.RIGHT, 0, :]).mean(axis=-2)


def to_diffusion(joints_xTx2x21x3: np.ndarray, convention: Convention = "paper") -> np.ndarray:
    """Diffusion features ``(..., T, 42, 4)``: centred xyz (§1.8) and the rotation scalar (§2.3).

    Rows 0–20 are the left hand. The centre subtracted is :func:`diffusion_center`; pass it to
    :func:`diffusion_to_joints` to restore absolute positions.
    """
    p = np.asarray(joints_xTx2x21x3)
    _check_trailing(p, (2, sk.NUM_JOINTS, 3), "to_diffusion", min_ndim=1)
    dt = _out_dtype(p)
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
    _check_trailing(x, DIFFUSION_SHAPE, "diffusion_to_joints", min_ndim=1)
    dt = _out_dtype(x)
    j = x[..., :3].reshape(*x.shape[:-2], 2, sk.NUM_JOINTS, 3)
    if center_x3 is None:
        return j.astype(dt, copy=True)
    c = np.asarray(center_x3, dtype=np.float64)
    return (j.astype(np.float64) + c[..., None, None, None, :]).astype(dt, copy=False)


# ----------------------------------------------------------------------------------------------
# §2.4 AR representation, 288 values per frame

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
    _check_trailing(R, (3, 3), "matrix_to_rotation_6d")
    return R[..., :2, :].reshape(*R.shape[:-2], 6)


def rotation_6d_to_matrix(d6_x6: np.ndarray) -> np.ndarray:
    """Gram–Schmidt 6D → rotation (§2.4 inverse, PyTorch3D): rows b1 = n(a1), b2 = n(a2 − (b1·a2)b1), b3 = b1×b2."""
    d6 = np.asarray(d6_x6)
    _check_trailing(d6, (6,), "rotation_6d_to_matrix")
    dt = _out_dtype(d6)
    d6 = d6.astype(np.float64, copy=False)
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1, _ = _normalize(a1, floor=1e-12)
    b2, _ = _normalize(a2 - np.sum(b1 * a2, -1, keepdims=True) * b1, floor=1e-12)
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
    _check_trailing(p, (2, sk.NUM_JOINTS, 3), "to_ar", min_ndim=1)
    dt = _out_dtype(p)
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
    _check_trailing(f, (AR_DIM,), "ar_to_joints", min_ndim=1)
    dt = _out_dtype(f)
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


# ----------------------------------------------------------------------------------------------
# §5.3 evaluator features

EVALUATOR_DIM = 2 * sk.NUM_JOINTS * 3


def to_evaluator(joints_xTx2x21x3: np.ndarray) -> np.ndarray:
    """Evaluator input ``(..., T, 126)`` (§5.3): subtract each frame's right-wrist position, flatten (hand, joint, xyz)."""
    p = np.asarray(joints_xTx2x21x3)
    _check_trailing(p, (2, sk.NUM_JOINTS, 3), "to_evaluator", min_ndim=1)
    dt = _out_dtype(p)
    # In the output precision: for float32 input the float32 difference is the correctly rounded one, which
    # a float64 difference cast back gave too, at 20x the time (0.85 -> 0.04 s CPU for 2,000 clips; this runs
    # on every evaluated batch).
    p = p.astype(dt, copy=False)
    rel = p - p[..., sk.RIGHT:sk.RIGHT + 1, 0:1, :]
    return rel.reshape(*p.shape[:-3], EVALUATOR_DIM)


# The "hand_frames" evaluator input: the same 126 values followed by features computed from them. It
# holds no information the 126 lack (it is a function of them, and contains them); it re-expresses
# what the captions talk about in the coordinates where it is simple, so a small evaluator learns it
# from far fewer samples: flexion is near-linear in a hand's own wrist frame (§2.1) but not in the
# camera frame, where the hand's orientation mixes into every joint; tip contacts are distances.
_PALM_JOINTS = tuple(sorted({j for tri in sk.PALM_TRIANGLES for j in tri}))
EVALUATOR_HAND_FRAMES_DIM = (EVALUATOR_DIM        # right-wrist-centred positions (§5.3)
                             + 2 * 20 * 3         # joints 1..20 in their own hand's wrist frame
                             + 2 * 9              # the two wrist frames (camera axes of x̂, ŷ, ẑ)
                             + 2 * 4              # thumb tip to the other four tips, per hand
                             + 5 * 5              # left tip to right tip
                             + 2 * 5)             # each tip to the other hand's palm centre


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` over the last axis, written out (several times faster on small trailing shapes)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def to_evaluator_hand_frames(joints_xTx2x21x3: np.ndarray) -> np.ndarray:
    """Evaluator input ``(..., T, 307)``: :func:`to_evaluator`'s 126 values, then local joint positions,
    wrist frames, intra-hand thumb-tip distances, inter-hand tip–tip and tip–palm-centre distances.

    Never raises on degenerate hands (generated motion may collapse a hand): a zero-length axis is
    normalised against a 1e-9 floor, so its features are zero instead of an error.
    """
    p = np.asarray(joints_xTx2x21x3)
    _check_trailing(p, (2, sk.NUM_JOINTS, 3), "to_evaluator_hand_frames", min_ndim=1)
    dt = _out_dtype(p)
    # Computed in the input's precision (float32 for training batches: this runs on the host per batch).
    p = p.astype(dt, copy=False)
    lead = p.shape[:-3]
    w = p[..., _WRIST, :]
    R, _ = _frame_axes(p, 1e-9)                                            # (..., 2, 3, 3), columns = axes
    local = (p[..., 1:, :] - w[..., None, :]) @ R                          # (..., 2, 20, 3): dᵀR = (Rᵀd)ᵀ
    tips = p[..., list(sk.TIPS), :]                                        # (..., 2, 5, 3)
    intra = np.linalg.norm(tips[..., 1:, :] - tips[..., :1, :], axis=-1)   # (..., 2, 4)
    inter = np.linalg.norm(tips[..., 0, :, None, :] - tips[..., 1, None, :, :], axis=-1)  # (..., 5, 5)
    palm = p[..., list(_PALM_JOINTS), :].mean(-2)                          # (..., 2, 3)
    tip_palm = np.linalg.norm(tips - palm[..., ::-1, None, :], axis=-1)    # (..., 2, 5): hand h → other palm
    parts = [to_evaluator(p), local, np.swapaxes(R, -1, -2), intra, inter, tip_palm]
    out = np.concatenate([x.reshape(*lead, -1) for x in parts], axis=-1)
    return out.astype(dt, copy=False)


EVALUATOR_INPUTS = {"positions": (to_evaluator, EVALUATOR_DIM),
                    "hand_frames": (to_evaluator_hand_frames, EVALUATOR_HAND_FRAMES_DIM)}


# ----------------------------------------------------------------------------------------------
# §1.8 normalisation statistics

@dataclass(frozen=True)
class NormStats:
    """Z-scoring statistics: ``normalize(x) = (x − mean) / (std + eps)``.

    ``mean`` and ``std`` have the feature shape ((42,4) diffusion, (288,) AR, (126,) evaluator) and are
    stored as float32. ``eps`` is 1e-6 for the AR preset (§1.8: loaders add 1e-6 to the std), else 0.
    The operators also work on JAX arrays.
    """

    mean: np.ndarray
    std: np.ndarray
    eps: float = 0.0

    def __post_init__(self) -> None:
        mean = np.array(self.mean, dtype=np.float32)
        std = np.array(self.std, dtype=np.float32)
        if mean.shape != std.shape:
            raise ValueError(f"NormStats: mean shape {mean.shape} != std shape {std.shape}")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(std))):
            raise ValueError("NormStats: mean/std contain non-finite values")
        if np.any(std + np.float32(self.eps) <= 0):
            raise ValueError("NormStats: std + eps must be positive")
        mean.setflags(write=False)
        std.setflags(write=False)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)
        object.__setattr__(self, "eps", float(self.eps))

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.mean.shape)

    def normalize(self, x):
        return (x - self.mean) / (self.std + np.float32(self.eps))

    def denormalize(self, z):
        return z * (self.std + np.float32(self.eps)) + self.mean

    def to_npz_dict(self, name: str) -> dict[str, np.ndarray]:
        """``{name}_mean``, ``{name}_std`` (the dataset's stats.npz keys) and ``{name}_eps``."""
        return {f"{name}_mean": self.mean, f"{name}_std": self.std, f"{name}_eps": np.asarray(self.eps)}

    @classmethod
    def from_npz_dict(cls, d: Mapping[str, np.ndarray], name: str, *, eps: float | None = None) -> NormStats:
        """Read back :meth:`to_npz_dict` output. ``eps`` precedence: argument, ``{name}_eps`` key, preset, 0."""
        try:
            mean, std = np.asarray(d[f"{name}_mean"]), np.asarray(d[f"{name}_std"])
        except KeyError as e:
            raise KeyError(f"normalisation stats {name!r}: missing key {e.args[0]!r}") from None
        if eps is None:
            if f"{name}_eps" in d:
                eps = float(np.asarray(d[f"{name}_eps"]))
            else:
                try:
                    eps = norm_preset(name).eps
                except ValueError:  # statistics no registered family or trainable declares
                    eps = 0.0
        return cls(mean=mean, std=std, eps=eps)


@dataclass(frozen=True)
class NormPreset:
    """How stats are computed for one representation (§1.8, §5.3): ``featurize(joints, convention)`` →
    features ending in ``feature_shape``; ``name`` is its ``stats.npz`` prefix. Which presets a family
    normalises with, and so which a dataset's ``stats.npz`` holds, is the registry's (``Family.norm``,
    ``families.TRAINABLE_NORMS``; :func:`norm_preset`)."""

    name: str
    feature_shape: tuple[int, ...]
    min_std: float
    eps: float = 0.0
    featurize: Callable[..., np.ndarray] | None = None


# The normalisation of each representation. §1.8: per (joint, channel), std < 1e-4 → 1, no eps.
DIFFUSION_NORM = NormPreset("diffusion", DIFFUSION_SHAPE, min_std=1e-4, featurize=to_diffusion)
# §1.8: per 288-d feature, std < 1e-6 → 1, loaders add 1e-6.
AR_NORM = NormPreset("ar", (AR_DIM,), min_std=1e-6, eps=1e-6,
                     featurize=lambda j, convention="paper": to_ar(j, convention=convention))
# §5.3 uses shipped mean/std_can_pos whose floor is unpublished; 1e-4 (as diffusion) maps the
# identically-zero right-wrist features to std 1.
EVALUATOR_NORM = NormPreset("evaluator", (EVALUATOR_DIM,), min_std=1e-4,
                            featurize=lambda j, convention="paper": to_evaluator(j))


def norm_preset(name: str) -> NormPreset:
    """The preset the registry declares under the ``stats.npz`` prefix ``name`` (``families.norm_presets``)."""
    from handx_jax.families import norm_presets

    presets = norm_presets()
    if name not in presets:
        raise ValueError(f"unknown normalisation preset {name!r}; expected one of {tuple(presets)}")
    return presets[name]


def _iter_chunks(x: np.ndarray | Iterable[np.ndarray], chunk_size: int) -> Iterator[np.ndarray]:
    if isinstance(x, np.ndarray):
        if x.ndim == 0:
            raise ValueError("compute_norm_stats: need at least one axis to reduce")
        for i in range(0, x.shape[0], chunk_size):
            yield x[i:i + chunk_size]
    else:
        for c in x:
            yield np.asarray(c)


def compute_norm_stats(x: np.ndarray | Iterable[np.ndarray], *, axis: int | tuple[int, ...] | None = None,
                       min_std: float, eps: float = 0.0, chunk_size: int = 1024) -> NormStats:
    """Mean/std over ``axis`` (reference §1.8), accumulated in float64 and streamed in chunks.

    ``x`` is an array (memory-mapped is fine: it is read ``chunk_size`` entries of axis 0 at a time)
    or an iterable of chunks that are concatenated along axis 0. ``axis`` (default: all but the last)
    must include 0. std = sqrt(max(E[x²] − E[x]², 0)); entries with std < min_std become 1.
    """
    if chunk_size < 1:
        raise ValueError("compute_norm_stats: chunk_size must be ≥ 1")
    s = ss = None
    n = 0
    axes: tuple[int, ...] | None = None
    feat_shape: tuple[int, ...] | None = None
    for c in _iter_chunks(x, chunk_size):
        if axes is None:
            nd = c.ndim
            raw = tuple(range(max(nd - 1, 1))) if axis is None else ((axis,) if isinstance(axis, int) else tuple(axis))
            axes = tuple(sorted({a % nd for a in raw})) if nd else ()
            if 0 not in axes:
                raise ValueError(f"compute_norm_stats: axis {axis} must include axis 0 (the streamed axis)")
            feat_shape = tuple(c.shape[a] for a in range(nd) if a not in axes)
        elif c.ndim != nd or tuple(c.shape[a] for a in range(nd) if a not in axes) != feat_shape:
            raise ValueError(f"compute_norm_stats: chunk shape {c.shape} does not match the first chunk")
        if c.shape[0] == 0:
            continue
        cs, css, cn = _moments(c, axes)
        s, ss = (cs, css) if s is None else (s + cs, ss + css)
        n += cn
    return _stats_from_sums(s, ss, n, min_std=min_std, eps=eps)


def _moments(c: np.ndarray, axes: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, int]:
    c64 = c.astype(np.float64, copy=False)
    return c64.sum(axis=axes), np.square(c64).sum(axis=axes), int(np.prod([c.shape[a] for a in axes]))


def _stats_from_sums(s, ss, n: int, *, min_std: float, eps: float) -> NormStats:
    if n == 0:
        raise ValueError("compute_norm_stats: no data")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(ss))):
        raise ValueError("compute_norm_stats: the data contain NaN or inf")
    mean = s / n
    std = np.sqrt(np.maximum(ss / n - mean * mean, 0.0))
    std = np.where(std < min_std, 1.0, std)
    return NormStats(mean=mean, std=std, eps=eps)


def compute_preset_stats(kind: str, features: np.ndarray | Iterable[np.ndarray], *,
                         chunk_size: int = 1024) -> NormStats:
    """Stats of already-computed features with the preset ``kind`` ("diffusion", "ar", "evaluator").

    Every axis before the preset's feature shape is reduced (e.g. clips and frames).
    """
    pr = norm_preset(kind)
    flat = (_flat_features(kind, c) for c in _iter_chunks(features, chunk_size))
    return compute_norm_stats(flat, axis=0, min_std=pr.min_std, eps=pr.eps, chunk_size=chunk_size)


def _flat_features(kind: str, c: np.ndarray) -> np.ndarray:
    fs = norm_preset(kind).feature_shape
    if c.ndim <= len(fs) or tuple(c.shape[-len(fs):]) != fs:
        raise ValueError(f"{kind} stats: features must end in {fs}, got {c.shape}")
    return c.reshape(-1, *fs)


def preset_moments(kind: str, features: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Float64 sum, sum of squares and count of one chunk of preset ``kind``'s features, reduced over
    every axis before the feature shape: what :func:`compute_preset_stats` adds up per chunk, for
    summing chunks computed elsewhere (another process) and finishing with :func:`stats_from_moments`."""
    return _moments(_flat_features(kind, np.asarray(features)), (0,))


def stats_from_moments(kind: str, s: np.ndarray, ss: np.ndarray, n: int) -> NormStats:
    """Mean/std under preset ``kind`` from summed :func:`preset_moments`."""
    pr = norm_preset(kind)
    return _stats_from_sums(s, ss, n, min_std=pr.min_std, eps=pr.eps)


def motion_norm_stats(kind: str, motion_NxTx2x21x3: np.ndarray, *, convention: Convention = "paper",
                      chunk_size: int = 256) -> NormStats:
    """Stats of representation ``kind`` over a (possibly memory-mapped) motion array, streamed by clips.

    Features are computed ``chunk_size`` clips at a time and reduced over clips and frames, so each
    clip counts once (§1.8).
    """
    featurize = norm_preset(kind).featurize
    m = motion_NxTx2x21x3
    if m.ndim != 5 or tuple(m.shape[2:]) != (2, sk.NUM_JOINTS, 3):
        raise ValueError(f"motion_norm_stats: expected (N, T, 2, 21, 3), got {tuple(m.shape)}")

    def feats() -> Iterator[np.ndarray]:
        for i in range(0, m.shape[0], chunk_size):
            yield featurize(np.asarray(m[i:i + chunk_size]), convention)

    return compute_preset_stats(kind, feats(), chunk_size=chunk_size)
