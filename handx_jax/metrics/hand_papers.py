"""The neighbouring hand papers' metrics (issue 33): G-HTT's MPJPE-RA / MPJPE-PA (per hand, root-aligned and
Procrustes-aligned) and APD, and BimArt's inter-hand penetration ("Pen 1cm") between the hands' surfaces (hand_surface.py)."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import hand_surface
from handx_jax.metrics.chunking import map_chunks


@jax.jit
def mpjpe_ra_mm(pred_NxTx2x21x3: jax.Array, gt_NxTx2x21x3: jax.Array) -> jax.Array:
    """MPJPE-RA per clip and hand (N, 2), mm: every frame's joints relative to that hand's wrist (the
    root of sk.CHAINS) in both, then the mean joint distance (G-HTT §4.2, "Root Aligned").

    G-HTT also equalises the mean palm-bone length of estimate and GT, against the scale ambiguity of
    pose estimation from images; generated and GT joints here share metric units, so no scale is
    applied (MPJPE-PA is the error with scale removed)."""
    return jnp.mean(joint_error_frames_mm(pred_NxTx2x21x3, gt_NxTx2x21x3, root_aligned=True), axis=1)


@partial(jax.jit, static_argnames=("root_aligned",))
def joint_error_frames_mm(pred_NxTx2x21x3: jax.Array, gt_NxTx2x21x3: jax.Array, *,
                          root_aligned: bool = True) -> jax.Array:
    """Mean joint distance per clip, frame and hand (N, T, 2), mm: MPJPE-RA's per-frame terms (each hand
    relative to its own wrist in both) or, with ``root_aligned=False``, the distance in the clip's shared
    frame. Per frame so that the prediction benchmark can bin it by horizon (evaluation/prediction.py)."""
    p, g = pred_NxTx2x21x3, gt_NxTx2x21x3
    if root_aligned:
        p, g = p - p[..., :1, :], g - g[..., :1, :]
    return 1000.0 * jnp.mean(jnp.linalg.norm(p - g, axis=-1), axis=3)


def procrustes_align(x_BxJx3: jax.Array, y_BxJx3: jax.Array) -> jax.Array:
    """``x`` mapped onto ``y`` by the similarity s·R·x + t (R a proper rotation, det +1; s > 0 uniform)
    minimising Σ_j ‖y_j − (s R x_j + t)‖², in closed form (Umeyama 1991), batched over leading axes.

    With H = Σ x̃_j ỹ_jᵀ = U S Vᵀ (x̃, ỹ centred): R = V D Uᵀ with D = diag(1, 1, det(V Uᵀ)), which
    keeps R a rotation where the best orthogonal map would be a reflection; s = tr(S D) / Σ‖x̃_j‖²;
    t = ȳ − s R x̄. A point set with no spread (all joints at one place) gets s = 0: every joint on ȳ.
    """
    mx, my = x_BxJx3.mean(-2, keepdims=True), y_BxJx3.mean(-2, keepdims=True)
    xc, yc = x_BxJx3 - mx, y_BxJx3 - my
    R, trace = best_rotation(xc, yc)
    var = jnp.sum(xc**2, axis=(-2, -1))
    s = trace / jnp.where(var > 0, var, 1.0)
    return s[..., None, None] * jnp.einsum("...ij,...kj->...ki", R, xc) + my


def best_rotation(x_BxJx3: jax.Array, y_BxJx3: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The proper rotation R (det +1) minimising Σ_j ‖y_j − R x_j‖² about the origin (Kabsch; centre both
    sets first for a fit about their centroids), batched over leading axes, and tr(S D), the correlation
    the similarity's scale divides (:func:`procrustes_align`). With H = Σ x_j y_jᵀ = U S Vᵀ: R = V D Uᵀ,
    D = diag(1, 1, det(V Uᵀ)), which keeps R a rotation where the best orthogonal map would be a reflection."""
    H = jnp.einsum("...ji,...jk->...ik", x_BxJx3, y_BxJx3)  # (B, 3, 3)
    U, S, Vt = jnp.linalg.svd(H)
    d = jnp.where(jnp.linalg.det(U) * jnp.linalg.det(Vt) < 0, -1.0, 1.0)  # det(V Uᵀ) = det(U) det(Vᵀ)
    D = jnp.stack([jnp.ones_like(d), jnp.ones_like(d), d], -1)  # (B, 3)
    return jnp.einsum("...ji,...j,...kj->...ik", Vt, D, U), jnp.sum(S * D, -1)  # V D Uᵀ


@jax.jit
def mpjpe_pa_mm(pred_NxTx2x21x3: jax.Array, gt_NxTx2x21x3: jax.Array) -> jax.Array:
    """MPJPE-PA per clip and hand (N, 2), mm: each hand of each frame aligned to the GT's by its own
    similarity Procrustes (:func:`procrustes_align`: rotation, uniform scale, translation), then the
    mean joint distance (G-HTT §4.2, "Procrustes Analysis of MPJPE")."""
    return jnp.mean(mpjpe_pa_frames_mm(pred_NxTx2x21x3, gt_NxTx2x21x3), axis=1)


@jax.jit
def mpjpe_pa_frames_mm(pred_NxTx2x21x3: jax.Array, gt_NxTx2x21x3: jax.Array) -> jax.Array:
    """MPJPE-PA's per-frame terms (N, T, 2), mm: :func:`mpjpe_pa_mm` before the mean over frames."""
    def one(p, g):
        return jnp.mean(jnp.linalg.norm(procrustes_align(p, g) - g, axis=-1), axis=3)

    return 1000.0 * map_chunks(one, pred_NxTx2x21x3, gt_NxTx2x21x3)


def apd_mm(samples_KxNxTx2x21x3) -> np.ndarray:
    """APD per prompt and hand (N, 2), mm: the mean over all pairs of the K samples of one prompt of the
    mean joint distance between the two samples (G-HTT supp. C.2, Eq. 13; APD is Yuan and Kitani's
    "average pairwise distance").

    Eq. 13 writes dist(hᵃ, hᵇ) as a SUM over frames and joints, but the APDs G-HTT reports (20–50 mm
    per hand over up to 96 frames × 20 joints, Tables 2–4) are only possible as the MEAN over them,
    which is what this computes; the 1/(K(K−1)) sum over ordered pairs a ≠ b equals the mean over the
    K(K−1)/2 unordered pairs. Joints are in the clip's shared frame (no root alignment), as in G-HTT's
    samples. K identical samples give 0; K < 2 has no pair and is refused.
    """
    return apd_frames_mm(samples_KxNxTx2x21x3).mean(1)


def apd_frames_mm(samples_KxNxTx2x21x3) -> np.ndarray:
    """APD's per-frame terms (N, T, 2), mm: :func:`apd_mm` before the mean over frames (the prediction
    benchmark bins them by horizon, evaluation/prediction.py)."""
    x = jnp.asarray(samples_KxNxTx2x21x3, jnp.float32)
    K = x.shape[0]
    if K < 2:
        raise ValueError(f"APD needs at least 2 samples per prompt, got {K}")
    a, b = np.triu_indices(K, 1)
    return np.asarray(_apd(x, jnp.asarray(a), jnp.asarray(b)), np.float64)


@jax.jit
def _apd(x_KxNxTx2x21x3, a_P, b_P):
    def add_pair(total_NxTx2, ab):  # one pair at a time: K(K−1)/2 = 190 pairs never in memory together
        d = jnp.linalg.norm(x_KxNxTx2x21x3[ab[0]] - x_KxNxTx2x21x3[ab[1]], axis=-1)  # (N, T, 2, 21)
        return total_NxTx2 + jnp.mean(d, axis=3), None

    N, T = x_KxNxTx2x21x3.shape[1:3]
    total, _ = jax.lax.scan(add_pair, jnp.zeros((N, T, 2), jnp.float32), jnp.stack([a_P, b_P], -1))
    return 1000.0 * total / a_P.shape[0]


@jax.jit
def interhand_penetration(joints_NxTx2x21x3: jax.Array) -> jax.Array:
    """Per frame (N, T), m: the deepest overlap between the two hands' surfaces (the bone and palm capsules
    of handx_jax/hand_surface.py, the one hand surface of the project), 0 where they do not touch.
    BimArt's "Pen 1cm" (§4, "Evaluation Metrics") is the share of frames where this exceeds 1 cm."""
    return map_chunks(hand_surface.interhand_penetration_depth, joints_NxTx2x21x3)


def penetration_stats(depth_NxT, threshold_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Per clip: % of frames penetrating deeper than ``threshold_m`` (BimArt's "Pen 1cm", %) and the
    mean over all frames of the per-frame depth (mm; frames without contact count 0)."""
    d = np.asarray(depth_NxT, np.float64)
    return 100.0 * (d > threshold_m).mean(1), 1000.0 * d.mean(1)

