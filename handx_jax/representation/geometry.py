"""Hand geometry shared by every representation (NumPy, pure, vectorised over leading batch axes; joints
``(..., 2, 21, 3)``, hand 0 = left; computed in float64, returned as float64 for float64 input and float32
otherwise): the wrist-anchored local frame (reference §2.1), local joint positions, and the rotation
scalar (§2.2 code, paper App. C)."""

from __future__ import annotations

from typing import Literal

import numpy as np

from handx_jax import skeleton as sk


Convention = Literal["paper", "code"]
CONVENTIONS: tuple[str, ...] = ("paper", "code")

# Interior joints (15 per hand) as (predecessor, joint, successor) index arrays, §2.2.
_TRI_15x3 = np.asarray(sk.INTERIOR_TRIPLES, dtype=np.int64)
WRIST, _INDEX_MCP, _MIDDLE_MCP, _PINKY_MCP = 0, 1, 4, 7
DEGENERATE_EPS = 1e-6  # metres for bone lengths, sin(angle) for the x̂ × ŷ₀ test


# ----------------------------------------------------------------------------------------------
# helpers

def out_dtype(x: np.ndarray) -> np.dtype:
    return np.dtype(np.float64) if x.dtype == np.float64 else np.dtype(np.float32)


def check_trailing(x: np.ndarray, trailing: tuple[int, ...], what: str, min_ndim: int = 0) -> None:
    n = len(trailing)
    if x.ndim < n + min_ndim or tuple(x.shape[x.ndim - n:]) != trailing:
        lead = "(..., T, " if min_ndim else "(..., "
        raise ValueError(
            f"{what}: expected shape {lead}{', '.join(map(str, trailing))}), got {tuple(x.shape)}"
        )


def unit_vectors(v: np.ndarray, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
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


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` over the last axis, written out (several times faster on small trailing shapes)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def wrist_frames(joints_x2x21x3: np.ndarray, *, eps: float = DEGENERATE_EPS) -> np.ndarray:
    """Wrist-anchored local frame per hand (reference §2.1), shape ``(..., 2, 3, 3)``.

    The COLUMNS of each matrix are the local axes: x̂ = n(middle MCP − wrist), ŷ₀ = n(index MCP − wrist),
    ẑ = n(x̂ × ŷ₀), ŷ = n(ẑ × x̂). Local coordinates of a point p are ``R.T @ (p − wrist)``.
    A zero-length x̂/ŷ₀ bone or parallel x̂, ŷ₀ (|x̂ × ŷ₀| ≤ eps) raises ValueError naming the first
    offending index. NaN input propagates (it is not reported as degenerate).
    """
    p = np.asarray(joints_x2x21x3)
    check_trailing(p, (2, sk.NUM_JOINTS, 3), "wrist_frames")
    dt = out_dtype(p)
    R, (nx, ny0, nz) = frame_axes(p.astype(np.float64, copy=False))
    _raise_degenerate(nx <= eps, "wrist and middle MCP coincide")
    _raise_degenerate(ny0 <= eps, "wrist and index MCP coincide")
    _raise_degenerate(nz <= eps, "wrist→middle-MCP and wrist→index-MCP are parallel")
    return R.astype(dt, copy=False)


def frame_axes(p: np.ndarray, floor: float = 0.0) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """§2.1 frames ``(..., 2, 3, 3)`` (columns x̂, ŷ, ẑ) in ``p``'s precision, and the norms of
    (middle MCP − wrist, index MCP − wrist, x̂ × ŷ₀) for the degeneracy checks. ``floor`` > 0 clamps
    the divisors, so degenerate hands give zero axes instead of NaN."""
    w = p[..., WRIST, :]
    ex, nx = unit_vectors(p[..., _MIDDLE_MCP, :] - w, floor)
    ey0, ny0 = unit_vectors(p[..., _INDEX_MCP, :] - w, floor)
    ez, nz = unit_vectors(cross(ex, ey0), floor)
    ey, _ = unit_vectors(cross(ez, ex), floor)
    return np.stack([ex, ey, ez], axis=-1), (nx, ny0, nz)


def local_positions(joints_x2x21x3: np.ndarray, rotations_x2x3x3: np.ndarray | None = None) -> np.ndarray:
    """``R_hᵀ (p_j − p_wrist)`` for all 21 joints, shape ``(..., 2, 21, 3)`` (wrist row is 0).

    ``rotations`` defaults to :func:`wrist_frames` (columns = local axes), giving §2.1's ``local(p)``.
    """
    p = np.asarray(joints_x2x21x3)
    check_trailing(p, (2, sk.NUM_JOINTS, 3), "local_positions")
    dt = out_dtype(p)
    p = p.astype(np.float64, copy=False)
    R = wrist_frames(p) if rotations_x2x3x3 is None else np.asarray(rotations_x2x3x3, dtype=np.float64)
    check_trailing(R, (2, 3, 3), "local_positions rotations")
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
    check_trailing(p, (2, sk.NUM_JOINTS, 3), "rotation_scalar")
    dt = out_dtype(p)
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
        n, nn = unit_vectors(p[..., _INDEX_MCP, :] - p[..., _PINKY_MCP, :])  # (..., 2, 3)
        _raise_degenerate(nn <= eps, "pinky MCP and index MCP coincide")
        n = n[..., None, :]
        up = u - np.sum(u * n, -1, keepdims=True) * n
        vp = v - np.sum(v * n, -1, keepdims=True) * n
        s = np.arctan2(np.linalg.norm(np.cross(up, vp), axis=-1), np.sum(up * vp, -1))
    out = np.zeros(p.shape[:-1], dtype=np.float64)
    out[..., _TRI_15x3[:, 1]] = s
    return out.astype(dt, copy=False)
