"""The six kinematic descriptors of the annotation pipeline, batched over clips.

Paper Appendix B and reference §6.1. Every function takes joints ``(N, T, 2, 21, 3)`` (float32,
metres, canonical frame, hand 0 = left) and returns per-frame descriptors:

=====================  ==========================  ===========================================
descriptor             array (``Features`` field)   definition
=====================  ==========================  ===========================================
finger flexing         ``flexion_NxTx2x14`` (rad)   signed bend angle at 14 joints per hand:
                                                    MCP/PIP/DIP of index, middle, ring, pinky,
                                                    then thumb MCP and IP (reference §6.1)
finger spacing         ``spacing_NxTx2x3`` (rad)    3-D angle between the MCP→PIP directions of
                                                    index–middle, middle–ring, ring–pinky
finger–finger (intra)  ``intra_tip_NxTx2x4`` (m)    thumb tip to index/middle/ring/pinky tip
finger–finger (inter)  ``inter_tip_NxTx5x5`` (m)    left tip a (rows) to right tip b (columns)
palm–palm relation     ``palm_dist_NxT`` (m),       palm clouds of both hands; the 30 closest
                       ``palm_vec_NxTx3`` (m)       pairs (paper) give the mean pair distance
                                                    and the mean left→right pair vector
finger–palm distance   ``finger_palm_NxTx2x5`` (m)  tip of hand h to the 5 closest points of
                                                    the other hand's palm cloud (mean distance)
wrist trajectory       ``wrist_NxTx2x3`` (m)        global wrist xyz
=====================  ==========================  ===========================================

Palm clouds (§5.4 "contact metrics", paper App. B): ``P`` points sampled in the four palm triangles
``skeleton.PALM_TRIANGLES`` with FIXED, SEEDED barycentric weights, so a cloud is the linear map
``W (P, 21) @ joints`` and is identical for every clip and every call (the reference redraws them
from an unseeded RNG, §9.17).

Angles are in radians; the state intervals of Table A are applied in ``events.py``.

One concern: the six descriptors and the palm clouds two of them share, computed in one float64 pass over
the same joints.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from handx_jax import skeleton as sk

# The 14 flexing joints (reference §6.1): non-thumb MCP/PIP/DIP in the order index, middle, ring,
# pinky, then thumb MCP and thumb IP. The thumb CMC is skipped. Each row is (predecessor, joint,
# successor) along the chain.
_FLEX_FINGERS = ("index", "middle", "ring", "pinky")
FLEX_TRIPLES = tuple(
    (sk.CHAINS[f][s - 1], sk.CHAINS[f][s], sk.CHAINS[f][s + 1]) for f in _FLEX_FINGERS for s in (1, 2, 3)
) + ((13, 14, 15), (14, 15, 16))
FLEX_JOINTS = tuple(sk.JOINT_NAMES[t[1]] for t in FLEX_TRIPLES)  # "index_mcp", ..., "thumb_ip"
NUM_FLEX = len(FLEX_TRIPLES)  # 14
_THUMB_MCP, _THUMB_IP = 12, 13  # positions in FLEX_TRIPLES

# Finger spacing pairs (reference §6.1) and their record keys (§6.3: "index, middle").
SPACING_PAIRS = (("index", "middle"), ("middle", "ring"), ("ring", "pinky"))
# Intra-hand tip pairs: thumb tip to the other four tips, record keys "index_tip, thumb_tip" (§6.3).
INTRA_TIP_FINGERS = ("index", "middle", "ring", "pinky")

_CONTACT_JOINTS = np.arange(16)  # joints 0–15 (everything but the tips), reference §5.4


@dataclass(frozen=True)
class FeatureConfig:
    """Descriptor constants (reference §6.1, §5.4; paper App. B)."""

    # Palm cloud size and the seed of its fixed barycentric weights (paper: 100 points).
    palm_points: int = 100
    palm_seed: int = 0
    # Palm–palm relation: number of closest pairs averaged (paper and code: 30).
    palm_pairs: int = 30
    # "closest_pairs" (paper App. B): the 30 closest of all P×P left/right pairs; distance = their
    # mean length, vector = their mean (right − left) vector.
    # "centroid" (reference code §6.1/§9.11): distance = mean of the 30 smallest nearest-neighbour
    # distances of the left points; vector = right centroid − left centroid.
    palm_relation: Literal["closest_pairs", "centroid"] = "closest_pairs"
    # Candidate points per palm in the pruned exact pair search (see _palm_pairs_closest); ≥ P
    # disables pruning. Only speed depends on it.
    prune_points: int = 32
    # Finger–palm distance: mean over this many closest palm points (paper and code: 5).
    finger_palm_k: int = 5
    # Flexion dead zone: bend magnitudes below this are set to 0 (reference §6.1: 11°).
    flex_dead_zone_deg: float = 11.0
    # Thumb MCP flexion. "reference" (§6.1): the full 3-D angle between the bones, signed by
    # −sign((û×v̂)·ẑ); when the bend lies mostly outside the plane normal to ẑ the sign is a coin
    # flip on a sizeable magnitude, so noise jumps it between ±|angle| (spurious hyperextension).
    # "projected" (the stable reading): the signed angle of the bend about −ẑ, atan2((u×v)·(−ẑ), u·v),
    # continuous in the joints, as the other fingers' angle is their bend about the local y axis.
    thumb_mcp: Literal["reference", "projected"] = "reference"
    # DIP–PIP coupling of the non-thumb fingers' flexion (0 = off, the reference: every joint's angle
    # from its own two bones). r > 0 (the stable reading): each finger's MCP, PIP and DIP angles are
    # fitted jointly under DIP = r·PIP, the flexor coupling of real fingers (r ≈ 2/3; the procedural
    # hands are built with exactly 2/3, synthesis/hand.DIP_PER_PIP). The fit weighs each bone's
    # observed direction by its squared length, as the direction of a short bone is the noisiest: the
    # distal phalanx (~2 cm) turns 3 mm of joint noise into ~9° of DIP angle, the fit into ~3°.
    dip_coupling: float = 0.0
    # Dataset contact statistic thresholds (reference §5.4): tip–tip across hands, tip–joints 0–15.
    contact_tip_tip_m: float = 0.02
    contact_tip_joint_m: float = 0.025
    # Frames processed at once in the palm–palm pair search (P²·4·chunk bytes; small keeps it in cache).
    frame_chunk: int = 512

    def __post_init__(self):
        if self.palm_points < 4:
            raise ValueError("palm_points must be at least 4 (one per palm triangle)")
        if not 1 <= self.palm_pairs <= self.palm_points:
            raise ValueError("palm_pairs must lie in [1, palm_points]")
        if not 1 <= self.finger_palm_k <= self.palm_points:
            raise ValueError("finger_palm_k must lie in [1, palm_points]")
        if not 0.0 <= self.dip_coupling <= 2.0:
            raise ValueError("dip_coupling must lie in [0, 2]")
        if self.thumb_mcp not in ("reference", "projected"):
            raise ValueError(f"unknown thumb_mcp {self.thumb_mcp!r}")
        if self.palm_relation not in ("closest_pairs", "centroid"):
            raise ValueError(f"unknown palm_relation {self.palm_relation!r}")


@dataclass(frozen=True)
class Features:
    """Per-frame descriptors of a batch of clips (see the module table)."""

    flexion_NxTx2x14: np.ndarray
    spacing_NxTx2x3: np.ndarray
    intra_tip_NxTx2x4: np.ndarray
    inter_tip_NxTx5x5: np.ndarray
    palm_dist_NxT: np.ndarray
    palm_vec_NxTx3: np.ndarray
    finger_palm_NxTx2x5: np.ndarray
    wrist_NxTx2x3: np.ndarray


# Working precision. The descriptors are returned as float32, but computed in float64: a float32
# kernel (arctan2, sqrt, a BLAS GEMM) may differ in its last bit between numpy/BLAS builds and CPUs,
# and the event thresholds then flip ~1 caption in 2000 (moving every such kernel by one ulp); in
# float64 such differences vanish when the result is rounded to float32, so one recipe gives one
# set of captions everywhere (issue 14.5).
_F = np.float64


def _as_joints(joints_NxTx2x21x3: np.ndarray) -> np.ndarray:
    x = np.asarray(joints_NxTx2x21x3, dtype=_F)
    if x.ndim != 5 or x.shape[2:] != (2, sk.NUM_JOINTS, 3):
        raise ValueError(f"expected joints of shape (N, T, 2, 21, 3), got {x.shape}")
    return x


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.sqrt(np.sum(v * v, axis=-1, keepdims=True))
    return v / np.maximum(n, 1e-12)


def _norm(v: np.ndarray) -> np.ndarray:
    return np.sqrt(np.sum(v * v, axis=-1))


def local_axes(joints_Nx2x21x3: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wrist-anchored local axes (x̂, ŷ, ẑ), each ``(..., 2, 3)`` (reference §2.1).

    x̂ points from the wrist to the middle MCP, ŷ toward the index MCP (made orthogonal), ẑ = x̂ × ŷ.
    """
    x = joints_Nx2x21x3
    w = x[..., 0, :]
    ax = _unit(x[..., 4, :] - w)
    ay0 = _unit(x[..., 1, :] - w)
    az = _unit(np.cross(ax, ay0))
    ay = np.cross(az, ax)
    return ax, ay, az


def finger_flexion(joints_NxTx2x21x3: np.ndarray, cfg: FeatureConfig = FeatureConfig()) -> np.ndarray:
    """Signed flexion angle (rad) at the 14 ``FLEX_JOINTS`` of each hand, shape (..., 2, 14).

    Reference §6.1. With u = joint − predecessor and v = successor − joint expressed in the local
    frame (§2.1): non-thumb joints drop the local y (lateral) component and take the signed angle in
    the x–z plane, sign = sign((û×v̂)_y), negated for the left hand, so that bending toward the palm
    is positive and bending backwards (hyperextension) negative for both hands. The thumb MCP uses
    full 3-D vectors with sign −sign((û×v̂)·ẑ); the thumb IP is unsigned. Magnitudes under the
    dead zone (11°) become 0. A straight finger gives 0.
    """
    x = np.asarray(joints_NxTx2x21x3, dtype=_F)
    ax, ay, az = local_axes(x)
    tri = np.asarray(FLEX_TRIPLES)
    u = x[..., tri[:, 1], :] - x[..., tri[:, 0], :]  # (..., 2, 14, 3)
    v = x[..., tri[:, 2], :] - x[..., tri[:, 1], :]
    ax_, az_ = ax[..., None, :], az[..., None, :]
    ux, uz = np.sum(u * ax_, -1), np.sum(u * az_, -1)
    vx, vz = np.sum(v * ax_, -1), np.sum(v * az_, -1)
    # Non-thumb: signed angle in the local x–z plane; (u×v)_y = u_z v_x − u_x v_z.
    cross_y = uz * vx - ux * vz
    dot_xz = ux * vx + uz * vz
    ang = np.arctan2(cross_y, dot_xz)
    hand_sign = np.array([-1.0, 1.0], dtype=np.float32)[:, None]  # left hand negated
    ang = ang * hand_sign
    # Thumb MCP (signed by −(u×v)·ẑ) and thumb IP (unsigned), full 3-D.
    ut, vt = u[..., _THUMB_MCP:, :], v[..., _THUMB_MCP:, :]
    c = np.cross(ut, vt)
    mag = np.arctan2(_norm(c), np.sum(ut * vt, -1))  # (..., 2, 2)
    if cfg.thumb_mcp == "projected":
        ang[..., _THUMB_MCP] = np.arctan2(-np.sum(c[..., 0, :] * az, -1), np.sum(ut[..., 0, :] * vt[..., 0, :], -1))
    else:
        sgn_mcp = -np.sign(np.sum(c[..., 0, :] * az, -1))
        sgn_mcp = np.where(sgn_mcp == 0, 1.0, sgn_mcp)
        ang[..., _THUMB_MCP] = mag[..., 0] * sgn_mcp
    ang[..., _THUMB_IP] = mag[..., 1]
    if cfg.dip_coupling > 0:
        ang[..., :_THUMB_MCP] = _coupled_fit(ang[..., :_THUMB_MCP], u[..., :_THUMB_MCP, :], v[..., :_THUMB_MCP, :],
                                             np.broadcast_to(ax_, u.shape)[..., :_THUMB_MCP, :],
                                             np.broadcast_to(az_, u.shape)[..., :_THUMB_MCP, :], cfg.dip_coupling)
    dead = np.deg2rad(cfg.flex_dead_zone_deg)
    return np.where(np.abs(ang) < dead, 0.0, ang).astype(np.float32)


def _coupled_fit(ang_x12: np.ndarray, u_x12x3: np.ndarray, v_x12x3: np.ndarray, ax_: np.ndarray, az_: np.ndarray,
                 r: float) -> np.ndarray:
    """The four fingers' (MCP, PIP, DIP) planar angles fitted under DIP = r·PIP (FeatureConfig.dip_coupling).

    In the local x–z plane the proximal, middle and distal phalanges point at φ1, φ2 = φ1 + p and
    φ3 = φ1 + (1 + r)·p. With the observed angles M, P, D (so the observed directions are φ0 + M,
    + P, + D) and a = the correction of φ1, minimise Σ_k w_k (model_k − observed_k)² with w_k the
    squared in-plane length of bone k (angular noise of a direction ∝ 1/length): a 2×2 linear system
    in (a, p) per finger and frame. MCP' = M + a, PIP' = p, DIP' = r·p. Exact when the observations
    obey the coupling.
    """
    shp = ang_x12.shape
    A = ang_x12.reshape(*shp[:-1], 4, 3)
    M, P, D = A[..., 0], A[..., 1], A[..., 2]
    # In-plane lengths: bone MCP→PIP is v of the MCP triple, PIP→DIP is v of PIP, DIP→tip is v of DIP.
    v = v_x12x3.reshape(*shp[:-1], 4, 3, 3)
    axr = ax_.reshape(*shp[:-1], 4, 3, 3)
    azr = az_.reshape(*shp[:-1], 4, 3, 3)
    l2 = np.sum(v * axr, -1) ** 2 + np.sum(v * azr, -1) ** 2  # (..., 4, 3)
    w1, w2, w3 = (np.maximum(l2[..., k], 1e-8) for k in range(3))
    c = 1.0 + r
    Q = P + D
    a11, a12, a22 = w1 + w2 + w3, w2 + c * w3, w2 + c * c * w3
    b1, b2 = w2 * P + w3 * Q, w2 * P + c * w3 * Q
    det = a11 * a22 - a12 * a12
    a = (b1 * a22 - a12 * b2) / det
    p = (a11 * b2 - a12 * b1) / det
    out = np.stack([M + a, p, r * p], -1)
    return out.reshape(shp)


def finger_spacing(joints_NxTx2x21x3: np.ndarray) -> np.ndarray:
    """Angle (rad) between the MCP→PIP directions of adjacent fingers, shape (..., 2, 3)."""
    x = np.asarray(joints_NxTx2x21x3, dtype=_F)
    d = {f: x[..., sk.CHAINS[f][2], :] - x[..., sk.CHAINS[f][1], :] for f in _FLEX_FINGERS}
    out = []
    for a, b in SPACING_PAIRS:
        out.append(np.arctan2(_norm(np.cross(d[a], d[b])), np.sum(d[a] * d[b], -1)))
    return np.stack(out, -1).astype(np.float32)


def tip_distances(joints_NxTx2x21x3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intra-hand thumb-tip distances ``(..., 2, 4)`` and inter-hand tip pairs ``(..., 5, 5)``."""
    x = np.asarray(joints_NxTx2x21x3, dtype=_F)
    tips = x[..., list(sk.TIPS), :]  # (..., 2, 5, 3) thumb..pinky
    intra = _norm(tips[..., 1:, :] - tips[..., :1, :])
    inter = _norm(tips[..., 0, :, None, :] - tips[..., 1, None, :, :])
    return intra, inter


def palm_weights(cfg: FeatureConfig = FeatureConfig()) -> np.ndarray:
    """Fixed barycentric map ``W (P, 21)``: palm cloud = W @ joints of one hand (float32).

    Points are split as evenly as possible over the four ``PALM_TRIANGLES`` (25 each for P = 100)
    and drawn uniformly inside each triangle with the square-root trick, from ``palm_seed``.
    """
    rng = np.random.default_rng(cfg.palm_seed)
    P = cfg.palm_points
    ntri = len(sk.PALM_TRIANGLES)
    W = np.zeros((P, sk.NUM_JOINTS), dtype=np.float64)
    row = 0
    for k, (a, b, c) in enumerate(sk.PALM_TRIANGLES):
        n = P // ntri + (1 if k < P % ntri else 0)
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        W[row:row + n, a] += 1.0 - s
        W[row:row + n, b] += s * (1.0 - r2)
        W[row:row + n, c] += s * r2
        row += n
    return W.astype(np.float32)


def palm_clouds(joints_NxTx2x21x3: np.ndarray, cfg: FeatureConfig = FeatureConfig(),
                W_Px21: np.ndarray | None = None) -> np.ndarray:
    """Palm point clouds ``(..., 2, P, 3)``, one linear map of the joints (a single GEMM)."""
    x = np.asarray(joints_NxTx2x21x3, dtype=_F)
    W = palm_weights(cfg) if W_Px21 is None else W_Px21
    lead = x.shape[:-2]
    flat = np.moveaxis(x.reshape(-1, sk.NUM_JOINTS, 3), 1, 0).reshape(sk.NUM_JOINTS, -1)
    cloud = (W @ flat).reshape(W.shape[0], -1, 3)
    return np.moveaxis(cloud, 0, 1).reshape(*lead, W.shape[0], 3)


def _sq_dists(a_MxPx3: np.ndarray, b_MxQx3: np.ndarray) -> np.ndarray:
    """Squared distances ``(M, P, Q)`` by one batched matmul of augmented vectors.

    |a − b|² = [a, |a|², 1] · [−2b, 1, |b|²]. Callers centre the points first so that float32
    cancellation stays far below the millimetre scale.
    """
    M, P, _ = a_MxPx3.shape
    Q = b_MxQx3.shape[1]
    A = np.empty((M, P, 5), a_MxPx3.dtype)
    A[..., :3] = a_MxPx3
    A[..., 3] = np.sum(a_MxPx3 * a_MxPx3, -1)
    A[..., 4] = 1.0
    B = np.empty((M, 5, Q), b_MxQx3.dtype)
    B[:, :3, :] = np.swapaxes(b_MxQx3, 1, 2) * -2.0
    B[:, 3, :] = 1.0
    B[:, 4, :] = np.sum(b_MxQx3 * b_MxQx3, -1)
    return np.maximum(np.matmul(A, B), 0.0)


def _mean_of_closest(D2_MxAxB: np.ndarray, a_MxAx3: np.ndarray, b_MxBx3: np.ndarray,
                     k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean distance and mean (b − a) vector over the k smallest entries of each frame's D2 block,
    and the k-th smallest distance. Exact ties at the k-th value are all averaged in.

    The vector sum needs no gather: Σ_pq [D2_pq ≤ τ](b_q − a_p) = Σ_q n_q b_q − Σ_p n_p a_p with
    n the column / row counts of the mask.
    """
    M, A, B = D2_MxAxB.shape
    flat = D2_MxAxB.reshape(M, A * B)
    tau = np.partition(flat, k - 1, axis=1)[:, k - 1]
    mask = D2_MxAxB <= tau[:, None, None]
    cnt = mask.sum((1, 2)).astype(D2_MxAxB.dtype)
    dsum = np.sum(np.sqrt(D2_MxAxB) * mask, axis=(1, 2))
    vsum = (np.einsum("mq,mqc->mc", mask.sum(1).astype(D2_MxAxB.dtype), b_MxBx3)
            - np.einsum("mp,mpc->mc", mask.sum(2).astype(D2_MxAxB.dtype), a_MxAx3))
    return dsum / cnt, vsum / cnt[:, None], np.sqrt(tau)


def _closest_full(cl_MxPx3: np.ndarray, cr_MxPx3: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Exhaustive search over all P² pairs.

    A pair among the k closest has D_pq ≤ δ_k ≤ τ_row (the k-th smallest row minimum: the k rows
    with the smallest minima already give k pairs within it), and likewise ≤ τ_col; so its row is
    among the k rows with the smallest minima and its column among the k such columns (barring
    exact ties). Only that k×k block is ranked.
    """
    M = cl_MxPx3.shape[0]
    D2 = _sq_dists(cl_MxPx3, cr_MxPx3)  # (M, P, P)
    rows = np.argpartition(D2.min(2), k - 1, axis=1)[:, :k]
    cols = np.argpartition(D2.min(1), k - 1, axis=1)[:, :k]
    mm = np.arange(M)[:, None]
    block = D2[mm[:, :, None], rows[:, :, None], cols[:, None, :]]
    d, v, _ = _mean_of_closest(block, cl_MxPx3[mm, rows], cr_MxPx3[mm, cols], k)
    return d, v


def _palm_pairs_closest(cl_MxPx3: np.ndarray, cr_MxPx3: np.ndarray, k: int,
                        m: int) -> tuple[np.ndarray, np.ndarray]:
    """Paper App. B: mean distance and mean (right − left) vector of the k closest of all P² pairs.

    Exact, with pruning: let d̂ be the direction between the cloud centroids and s the projections
    on it. Every pair satisfies |r_q − l_p| ≥ s(r_q) − s(l_p), so once the k closest pairs among the
    m left points with the largest s and the m right points with the smallest s are found, any pair
    outside that block is at least LB = min(min s_R − s_L^(m+1), s_R^(m+1) − max s_L) away. Frames
    where the block's k-th distance exceeds LB (palms overlapping along d̂) are searched exhaustively.
    """
    M, P, _ = cl_MxPx3.shape
    if m >= P or m * m < k:
        return _closest_full(cl_MxPx3, cr_MxPx3, k)
    mm = np.arange(M)[:, None]
    d = cr_MxPx3.mean(1) - cl_MxPx3.mean(1)
    d /= np.maximum(_norm(d), 1e-9)[:, None]
    sl = np.einsum("mpc,mc->mp", cl_MxPx3, d)
    sr = np.einsum("mpc,mc->mp", cr_MxPx3, d)
    lsel = np.argpartition(-sl, m, axis=1)  # [:m] the m largest, [m] the (m+1)-th largest
    rsel = np.argpartition(sr, m, axis=1)
    sl_next = np.take_along_axis(sl, lsel[:, m:m + 1], 1)[:, 0]
    sr_next = np.take_along_axis(sr, rsel[:, m:m + 1], 1)[:, 0]
    lb = np.minimum(sr.min(1) - sl_next, sr_next - sl.max(1))
    a, b = cl_MxPx3[mm, lsel[:, :m]], cr_MxPx3[mm, rsel[:, :m]]  # (M, m, 3)
    D2 = np.zeros((M, m, m), a.dtype)
    for c in range(3):
        D2 += np.square(b[:, None, :, c] - a[:, :, None, c])
    dist, vec, kth = _mean_of_closest(D2, a, b, k)
    bad = np.flatnonzero(~(kth <= lb))
    if len(bad):
        dist[bad], vec[bad] = _closest_full(cl_MxPx3[bad], cr_MxPx3[bad], k)
    return dist.astype(np.float32), vec.astype(np.float32)


def _palm_pairs_centroid(cl_MxPx3: np.ndarray, cr_MxPx3: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference code (§6.1, §9.11): mean of the k smallest nearest-neighbour distances of the left
    points; direction = right centroid − left centroid."""
    D2 = _sq_dists(cl_MxPx3, cr_MxPx3)
    nn = np.sqrt(D2.min(-1))
    dist = np.partition(nn, k - 1, axis=-1)[:, :k].mean(-1)
    vec = cr_MxPx3.mean(1) - cl_MxPx3.mean(1)
    return dist.astype(np.float32), vec.astype(np.float32)


def palm_relation(clouds_NxTx2xPx3: np.ndarray, cfg: FeatureConfig = FeatureConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Palm–palm distance ``(N, T)`` and left→right relation vector ``(N, T, 3)``."""
    c = np.asarray(clouds_NxTx2xPx3, dtype=_F)
    lead = c.shape[:-3]
    P = c.shape[-2]
    c = c.reshape(-1, 2, P, 3)
    M = c.shape[0]
    if cfg.palm_relation == "closest_pairs":
        fn = lambda a, b, k: _palm_pairs_closest(a, b, k, cfg.prune_points)
    else:
        fn = _palm_pairs_centroid
    dist, vec = np.empty(M, _F), np.empty((M, 3), _F)
    for s in range(0, M, cfg.frame_chunk):
        cc = c[s:s + cfg.frame_chunk]
        centre = cc.mean((1, 2), keepdims=True)  # per-frame centring keeps float32 exact enough
        cc = cc - centre
        dist[s:s + len(cc)], vec[s:s + len(cc)] = fn(cc[:, 0], cc[:, 1], cfg.palm_pairs)
    return dist.reshape(lead).astype(np.float32), vec.reshape(*lead, 3).astype(np.float32)


def finger_palm_distance(joints_NxTx2x21x3: np.ndarray, clouds_NxTx2xPx3: np.ndarray | None = None,
                         cfg: FeatureConfig = FeatureConfig(), W_Px21: np.ndarray | None = None) -> np.ndarray:
    """Mean distance of each tip of hand h to the k closest points of the OTHER hand's palm cloud.

    Shape (..., 2, 5): [h, finger] with fingers thumb..pinky (paper App. B, reference §6.1).
    Since palm point p is Σ_j W_pj J_j over the six palm joints, the tip·point products are one GEMM
    of the (tip · palm-joint) products with Wᵀ: |t − q_p|² = |t|² − 2 Σ_j W_pj (t·J_j) + |q_p|².
    The clouds themselves are therefore not needed (``clouds_NxTx2xPx3`` is only checked).
    """
    x = np.asarray(joints_NxTx2x21x3, dtype=_F)
    W = palm_weights(cfg) if W_Px21 is None else W_Px21
    if clouds_NxTx2xPx3 is not None and clouds_NxTx2xPx3.shape[-2] != W.shape[0]:
        raise ValueError("palm clouds and palm weights disagree on the number of points")
    lead = x.shape[:-3]
    P = W.shape[0]
    palm_j = np.flatnonzero(W.any(0))  # the six palm joints
    W6 = np.ascontiguousarray(W[:, palm_j].T)  # (6, P)
    xx = x.reshape(-1, 2, sk.NUM_JOINTS, 3)
    centre = xx[:, :, 0:1, :].mean(1, keepdims=True)  # between the wrists: keeps float32 exact
    xx = xx - centre
    tips = xx[:, :, list(sk.TIPS), :]  # (M, 2, 5, 3)
    J = xx[:, ::-1][:, :, palm_j, :]  # the other hand's palm joints, (M, 2, 6, 3)
    nj = len(palm_j)
    G = np.einsum("mhkc,mhjc->mhkj", tips, J)  # (M, 2, 5, 6) tip · palm joint
    d2 = (G.reshape(-1, nj) @ (-2.0 * W6)).reshape(-1, 2, 5, P)
    # |q_p|² = Σ_ij W_pi W_pj (J_i · J_j): one more GEMM from the palm joints' Gram matrices.
    gram = np.einsum("mhic,mhjc->mhij", J, J).reshape(-1, nj * nj)
    WW = (W6[:, None, :] * W6[None, :, :]).reshape(nj * nj, P)
    d2 += (gram @ WW).reshape(-1, 2, 1, P)
    d2 += np.sum(tips * tips, -1)[..., None]
    k = cfg.finger_palm_k
    near = np.partition(d2, k - 1, axis=-1)[..., :k]
    return np.sqrt(np.maximum(near, 0.0)).mean(-1).reshape(*lead, 2, 5).astype(np.float32)


def compute_features(joints_NxTx2x21x3: np.ndarray, cfg: FeatureConfig = FeatureConfig()) -> Features:
    """All six descriptors for a batch of clips."""
    x = _as_joints(joints_NxTx2x21x3)
    W = palm_weights(cfg)
    clouds = palm_clouds(x, cfg, W)
    intra, inter = tip_distances(x)
    pd, pv = palm_relation(clouds, cfg)
    return Features(
        flexion_NxTx2x14=finger_flexion(x, cfg),
        spacing_NxTx2x3=finger_spacing(x),
        intra_tip_NxTx2x4=intra.astype(np.float32),
        inter_tip_NxTx5x5=inter.astype(np.float32),
        palm_dist_NxT=pd,
        palm_vec_NxTx3=pv,
        finger_palm_NxTx2x5=finger_palm_distance(x, clouds, cfg, W),
        wrist_NxTx2x3=np.ascontiguousarray(x[..., 0, :], dtype=np.float32),
    )


# ---------------------------------------------------------------------------------------------
# Dataset contact statistics (reference §5.4 "Dataset contact statistics"; paper A.5, Table 1(b)).


def contact_frames(joints_NxTx2x21x3: np.ndarray, cfg: FeatureConfig = FeatureConfig()) -> np.ndarray:
    """Per-frame inter-hand contact ``(N, T)`` bool.

    A frame is in contact if some left tip and right tip are closer than 2 cm, or some tip of one
    hand is closer than 2.5 cm to one of the other hand's joints 0–15.
    """
    x = _as_joints(joints_NxTx2x21x3)
    tips = x[..., list(sk.TIPS), :]  # (N, T, 2, 5, 3)
    _, inter = tip_distances(x)
    tt = inter.reshape(*inter.shape[:-2], -1).min(-1) < cfg.contact_tip_tip_m
    body = x[..., _CONTACT_JOINTS, :]  # (N, T, 2, 16, 3)
    l2r = _norm(tips[..., 0, :, None, :] - body[..., 1, None, :, :]).reshape(*x.shape[:2], -1).min(-1)
    r2l = _norm(tips[..., 1, :, None, :] - body[..., 0, None, :, :]).reshape(*x.shape[:2], -1).min(-1)
    return tt | (np.minimum(l2r, r2l) < cfg.contact_tip_joint_m)


def contact_segments_stats(contact_NxT: np.ndarray, fps: int = sk.FPS) -> dict[str, float]:
    """Table 1(b) contact quantities of a corpus from per-frame contact flags (paper A.5).

    ``ratio``: contact frames / all frames. ``duration_s``: mean length of the maximal contact runs
    (pooled over clips; runs are cut at clip borders) in seconds. ``events_per_min``: number of runs
    per minute of motion. Also ``segments`` and ``frames``.
    """
    c = np.asarray(contact_NxT, dtype=bool)
    if c.ndim != 2:
        raise ValueError(f"expected contact flags of shape (N, T), got {c.shape}")
    N, T = c.shape
    frames = N * T
    if frames == 0:
        return {"ratio": 0.0, "duration_s": 0.0, "events_per_min": 0.0, "segments": 0, "frames": 0}
    d = np.diff(np.pad(c.astype(np.int8), ((0, 0), (1, 1))), axis=1)
    starts, ends = np.nonzero(d == 1)[1], np.nonzero(d == -1)[1]
    lengths = ends - starts
    segs = len(lengths)
    return {
        "ratio": float(c.sum() / frames),
        "duration_s": float(lengths.mean() / fps) if segs else 0.0,
        "events_per_min": float(segs / (frames / fps / 60.0)),
        "segments": int(segs),
        "frames": int(frames),
    }
