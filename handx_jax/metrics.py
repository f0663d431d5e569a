"""The paper's evaluation metrics, jitted and batched (reference §5.4; paper §6, E.2).

Embedding metrics take evaluator embeddings (text ``T_NxD``, motion ``M_NxD``); motion metrics take
joints ``(N, 60, 2, 21, 3)`` in metres. Every randomised quantity (block order, diversity pairs,
MultiModality groups, palm samples) is drawn from an explicit seed: the reference's unseeded draws
(§9.17) are not ported. Beside the paper's metrics, the neighbouring hand papers' (issue 33): G-HTT's
MPJPE-RA / MPJPE-PA and APD, BimArt's inter-hand penetration ("Pen 1cm") and contact feasibility.

Replications and confidence intervals (issues 4 and 14.2). Every ± is a 95% interval computed over
values that are independent of each other, and the output says which (:func:`ci_method`):

* "groups": with G > 1 generation groups (samples per prompt), each metric is computed per group and
  the interval is the Student-t one over the G group values, t_{0.975, G−1}·s/√G (s with ddof 1).
  Groups are independent draws from the generator for the same prompts, so the interval covers the
  generation randomness, not the choice of prompts.
* "bootstrap_prompts": with one group (the Ground Truth row, or G = 1), and for MultiModality (which
  is a between-group quantity), the prompts are resampled with replacement ``cfg.bootstrap`` times
  and the interval is 1.96 × the standard deviation of the statistic over the resamples.

R-Precision blocks, Diversity pairs and MultiModality picks are still re-drawn ``replications`` times
(replication r uses its own prompt order and pairs, seeded by (seed, r)) and averaged: the
re-blockings reduce the variance of the point value, but they reuse the same samples, so their
spread is not an interval (it shrinks with R and is 0 when nothing is random: FID's old "CI" over
replications was 3e-15 for one group). In particular R-Precision's ± here is *not* the paper's: the
reference reports the standard deviation of the per-block scores over all blocks of all groups
(reference §5.4; ≈ √(p(1−p)/32) ≈ 0.08 for block 32 whatever N is), a spread of single-block
scores, while this ± is an interval for the mean and shrinks as 1/√G (groups) or 1/√N (bootstrap).
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import skeleton as sk


@dataclass(frozen=True)
class MetricConfig:
    rprec_block: int = 32  # 32 in Table 2; 16 in Table B / Fig. 4
    top_k: int = 3
    diversity_pairs: int = 300
    multimodality_pairs: int = 20
    replications: int = 20  # re-blockings / re-drawn pairs averaged into each point value
    bootstrap: int = 200  # prompt resamples for the "bootstrap_prompts" intervals
    seed: int = 0
    intra_contact_m: float = 0.020  # thumb tip vs other tips (reference §5.4)
    inter_contact_m: float = 0.025  # tips vs the other hand's palm cloud
    palm_points: int = 100
    # MPJPE root: "none" = positions in the shared clip frame (paper reading); "left_wrist"
    # reproduces the official script, which ends up relative to each frame's left wrist (§9.17).
    mpjpe_root: str = "none"
    # APD over the first K generation groups of each prompt (G-HTT: K = 20); 0 = all groups.
    apd_samples: int = 0
    pen_threshold_m: float = 0.01  # BimArt's "Pen 1cm"


# ------------------------------------------------------------------------------------------------
# Embedding metrics


@jax.jit
def pairwise_dist(a_NxD: jax.Array, b_MxD: jax.Array) -> jax.Array:
    """Euclidean distance matrix (N, M), computed stably in the expanded form."""
    d2 = (jnp.sum(a_NxD**2, -1)[:, None] + jnp.sum(b_MxD**2, -1)[None, :] - 2.0 * a_NxD @ b_MxD.T)
    return jnp.sqrt(jnp.maximum(d2, 0.0))


@partial(jax.jit, static_argnames=("block", "top_k"))
def r_precision(text_NxD: jax.Array, motion_NxD: jax.Array, block: int = 32, top_k: int = 3):
    """R-Precision top-1..k and MM-Dist over consecutive blocks (reference §5.4).

    Items are split into blocks of ``block`` in the given order; the N mod block remainder is
    dropped (one block of all N if N < block). A hit at k: the matching motion is among the k nearest
    motions of its text. Returns (top-k fractions (top_k,), MM-Dist = mean matched distance).
    """
    n = text_NxD.shape[0]
    b = block if n >= block else n
    nb = n // b
    t = text_NxD[: nb * b].reshape(nb, b, -1)
    m = motion_NxD[: nb * b].reshape(nb, b, -1)
    d = jax.vmap(pairwise_dist)(t, m)  # (nb, b, b)
    diag = jnp.diagonal(d, axis1=1, axis2=2)  # (nb, b)
    closer, tied = _closer_and_tied(d, diag)
    hits = jnp.stack([jnp.mean(expected_hit(closer, tied, k)) for k in range(1, top_k + 1)])
    return hits, jnp.mean(diag)


def _closer_and_tied(d_NBxBxB: jax.Array, diag_NBxB: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Per text: how many motions of its block are strictly closer than its own, and how many OTHER motions
    are exactly as close (identical generated motions give identical embeddings, so identical distances)."""
    closer = jnp.sum(d_NBxBxB < diag_NBxB[..., None], axis=-1)
    tied = jnp.sum(d_NBxBxB == diag_NBxB[..., None], axis=-1) - 1  # the matching motion ties with itself
    return closer, tied


def expected_hit(closer, tied, k: int):
    """P(the matching motion is among the k nearest) when ties are broken uniformly at random: its rank is
    ``closer + U``, U uniform on {0, …, tied}. Counting only strictly closer motions (rank = closer) scores a
    collapsed generator, whose samples are all the same motion, as perfectly aligned (every text a hit);
    this scores it at chance, k / block."""
    return jnp.clip((k - closer) / (tied + 1.0), 0.0, 1.0)


@functools.cache
def _openblas_threads() -> tuple | None:
    """(get, set) of the thread count of NumPy's bundled OpenBLAS, or None where there is none to find.

    The same ctypes calls threadpoolctl makes (not a dependency here)."""
    import ctypes
    import glob
    import os

    libs = os.path.join(os.path.dirname(os.path.dirname(np.__file__)), "numpy.libs")
    for path in sorted(glob.glob(os.path.join(libs, "*openblas*.so*"))):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for pre, suf in (("scipy_openblas", "64_"), ("scipy_openblas", "_64_"), ("openblas", "64_"), ("openblas", "")):
            get, set_ = (getattr(lib, f"{pre}_{f}_num_threads{suf}", None) for f in ("get", "set"))
            if get is not None and set_ is not None:
                return get, set_
    return None


@contextlib.contextmanager
def _blas_single_thread():
    """Run NumPy's BLAS/LAPACK on one thread inside the block.

    The bootstrap's stacked 128² Cholesky / matmul / eigvalsh calls are each too small to split, but
    OpenBLAS threads them anyway (its potrf always; gemm above 64³): with 2 threads on this 2-core CPU
    shared with a training run they took 2.9 s of CPU (50 s wall at load 16) instead of 0.02 s each.
    The resampled Gram and distance matmuls are used single-threaded too: on a quiet machine a second
    thread saves ~0.1 s, on one shared with a training run (the usual case in a sweep) OpenBLAS's
    spinning threads cost several seconds of wall time (FID part 4.5 s wall for ~1 s CPU at load 12).
    """
    fns = _openblas_threads()
    if fns is None:
        yield
        return
    get, set_ = fns
    n = get()
    set_(1)
    try:
        yield
    finally:
        set_(n)


def _trace_sqrt_product(s1_BxDxD: np.ndarray, s2_BxDxD: np.ndarray) -> np.ndarray:
    """Tr sqrtm(Σ1 Σ2) of each pair of a batch (B,), float64 on the host.

    Σ1Σ2 is similar to L1ᵀ Σ2 L1 with Σ1 = L1 L1ᵀ (Cholesky): a symmetric PSD matrix with the same
    eigenvalues, so the trace of the square root is Σ sqrt(eigvalsh(L1ᵀ Σ2 L1)), with no non-symmetric
    ``scipy.linalg.sqrtm`` (the usual FID code; tests/test_metrics.py checks the two agree). With the
    Gram matmul of :func:`resampled_moments` this takes 200 resamples of 128-d embeddings in ~0.7 s of
    CPU, where a float64 ``lax.map`` of gather + ``jnp.cov`` + ``jnp.linalg.eigh`` took ~31 s. A singular Σ1 (fewer samples than dimensions, a collapsed
    embedding) has no Cholesky factor: its symmetric square root from ``eigh`` (same eigenvalues of the
    product, about twice the cost) takes the place of L1 then.
    """
    s1, s2 = np.asarray(s1_BxDxD, np.float64), np.asarray(s2_BxDxD, np.float64)
    with _blas_single_thread():
        try:
            l1 = np.linalg.cholesky(s1)
        except np.linalg.LinAlgError:
            w, v = np.linalg.eigh(s1)
            l1 = (v * np.sqrt(np.clip(w, 0.0, None))[..., None, :]) @ np.swapaxes(v, -1, -2)
        m = np.swapaxes(l1, -1, -2) @ s2 @ l1
        ev = np.linalg.eigvalsh(0.5 * (m + np.swapaxes(m, -1, -2)))
    return np.sqrt(np.clip(ev, 0.0, None)).sum(-1)


def _fid_from_moments(mu1_BxD, s1_BxDxD, mu2_BxD, s2_BxDxD) -> np.ndarray:
    """Fréchet distance (B,) of Gaussians N(μ1, Σ1), N(μ2, Σ2): |μ1 − μ2|² + Tr Σ1 + Tr Σ2 − 2 Tr sqrt(Σ1Σ2)."""
    return (np.sum((mu1_BxD - mu2_BxD) ** 2, -1) + np.trace(s1_BxDxD, axis1=-2, axis2=-1)
            + np.trace(s2_BxDxD, axis1=-2, axis2=-1) - 2.0 * _trace_sqrt_product(s1_BxDxD, s2_BxDxD))


def fid(a_NxD, b_MxD) -> float:
    """Fréchet distance between Gaussian fits (mean, covariance with ddof 1) of two embedding sets,
    computed in float64 (the cancellation of the traces against 2 Tr sqrt(Σ1Σ2) needs it)."""
    a, b = np.asarray(a_NxD, np.float64), np.asarray(b_MxD, np.float64)
    v = _fid_from_moments(a.mean(0)[None], np.cov(a, rowvar=False)[None], b.mean(0)[None],
                          np.cov(b, rowvar=False)[None])[0]
    return float(max(v, 0.0))


GRAM_CHUNK = 256  # prompts per step of the resampled Gram: its (chunk, D(D+1)/2) products stay ~8 MB


def resampled_moments(x_NxD, counts_BxN) -> tuple[np.ndarray, np.ndarray]:
    """Mean (B, D) and covariance (B, D, D), ddof 1, of every bootstrap resample of the rows of ``x``,
    float64, without materialising the resamples.

    Resample b holds row n ``counts[b, n]`` times (its multiplicities, :func:`_counts`), so with
    x̃ = x − mean(x) its Gram matrix is Σ_n c_bn x̃_n x̃_nᵀ = G + Σ_n (c_bn − 1) x̃_n x̃_nᵀ, G = x̃ᵀx̃:
    one (B, N) @ (N, D(D+1)/2) product for all resamples at once over the upper triangle of the outer
    products, instead of B gathers of (N, D) and B covariances. G is exact in float64; the correction,
    whose partial sums grow as √N rather than N, is a float32 matmul (half the float64 time) and stays
    within ~1e-8 of the float64 result relative to G. Centring first keeps the subtraction of the
    resample mean benign. Equal to ``np.mean`` / ``np.cov`` of ``x[idx_b]`` to that tolerance
    (tests/test_metrics.py).
    """
    x = np.asarray(x_NxD, np.float64)
    c = np.asarray(counts_BxN, np.float64)
    (n, d), B = x.shape, c.shape[0]
    m_B = c.sum(1)
    xc = x - x.mean(0)
    mean_BxD = (c @ xc) / m_B[:, None]
    iu, ju = np.triu_indices(d)
    dc, xc32 = (c - 1.0).astype(np.float32), xc.astype(np.float32)
    upper = np.zeros((B, len(iu)), np.float32)
    for s in range(0, n, GRAM_CHUNK):
        blk = xc32[s:s + GRAM_CHUNK]
        upper += dc[:, s:s + GRAM_CHUNK] @ (blk[:, iu] * blk[:, ju])
    gram = np.empty((B, d, d))
    gram[:, iu, ju] = upper
    gram[:, ju, iu] = upper
    gram += xc.T @ xc
    cov = (gram - m_B[:, None, None] * mean_BxD[:, :, None] * mean_BxD[:, None, :]) / (m_B - 1.0)[:, None, None]
    return mean_BxD + x.mean(0), cov


def fid_resampled(a_NxD, b_NxD, counts_BxN) -> np.ndarray:
    """FID (B,) of each paired bootstrap resample: resample b takes prompt n ``counts[b, n]`` times on
    both sides (a and b are aligned by prompt). Same values as :func:`fid` on ``a[idx_b], b[idx_b]``."""
    with _blas_single_thread():
        mu1, s1 = resampled_moments(a_NxD, counts_BxN)
        mu2, s2 = resampled_moments(b_NxD, counts_BxN)
        return np.maximum(_fid_from_moments(mu1, s1, mu2, s2), 0.0)


@jax.jit
def diversity(emb_NxD: jax.Array, idx1: jax.Array, idx2: jax.Array) -> jax.Array:
    """Mean L2 distance between two index sets of embeddings."""
    return jnp.mean(jnp.linalg.norm(emb_NxD[idx1] - emb_NxD[idx2], axis=-1))


def diversity_indices(n: int, pairs: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Two index sets without replacement (reference: n = min(N−1, 300), fixed per evaluation)."""
    k = min(n - 1, pairs)
    rng = np.random.default_rng([seed, 0xD1])
    return rng.choice(n, k, replace=False), rng.choice(n, k, replace=False)


@jax.jit
def multimodality(emb_NxGxD: jax.Array, g1: jax.Array, g2: jax.Array) -> jax.Array:
    """Mean distance between generations of the same prompt (groups g1 vs g2)."""
    return jnp.mean(jnp.linalg.norm(emb_NxGxD[:, g1] - emb_NxGxD[:, g2], axis=-1))


# ------------------------------------------------------------------------------------------------
# Motion metrics


def mpjpe_mm(pred_NxTx2x21x3, gt_NxTx2x21x3, root: str = "none") -> jax.Array:
    """Mean per-joint position error in millimetres, per clip (N,)."""
    if root not in ("none", "left_wrist", "per_hand_wrist"):
        raise ValueError(f"unknown MPJPE root {root!r}")
    return _mpjpe_mm(jnp.asarray(pred_NxTx2x21x3), jnp.asarray(gt_NxTx2x21x3), root)


@partial(jax.jit, static_argnames=("root",))
def _mpjpe_mm(p, g, root: str):
    # One fused pass (the eager version made a full-size temporary per op: 0.33 s CPU for 2,000 clips).
    if root == "left_wrist":
        p = p - p[:, :, :1, :1]
        g = g - g[:, :, :1, :1]
    elif root == "per_hand_wrist":
        p = p - p[:, :, :, :1]
        g = g - g[:, :, :, :1]
    return 1000.0 * jnp.mean(jnp.linalg.norm(p - g, axis=-1), axis=(1, 2, 3))


@partial(jax.jit, static_argnames=("fps",))
def acceleration_jitter(joints_NxTx2x21x3: jax.Array, fps: int = sk.FPS):
    """Mean joint acceleration (m/s²) and jitter (m/s³, third difference) per clip."""
    x = joints_NxTx2x21x3
    acc = jnp.diff(x, n=2, axis=1) * fps**2
    jerk = jnp.diff(x, n=3, axis=1) * fps**3
    return jnp.linalg.norm(acc, axis=-1).mean((1, 2, 3)), jnp.linalg.norm(jerk, axis=-1).mean((1, 2, 3))


def palm_barycentric(points: int = 100, seed: int = 0) -> np.ndarray:
    """(P, 21) weights of the palm cloud: uniform samples in the four palm triangles (reference §5.4).

    The same sampler as the annotation pipeline's palm clouds (``features.palm_weights``), fixed by the
    seed (the reference redraws them unseeded on every call, §9.17).
    """
    from handx_jax.data.features import FeatureConfig, palm_weights

    return palm_weights(FeatureConfig(palm_points=points, palm_seed=seed))


CONTACT_CHUNK = 50  # clips per step of the tip-to-palm scan: its (chunk, T, 5, P) distances stay in cache


def _tip_palm_min_dist(x_CxTx2x21x3: jax.Array, palm_Px21: jax.Array) -> jax.Array:
    """Distance (C, T, 2, 5) from each tip of hand h to the nearest point of the other hand's palm cloud.

    Coordinate-major layout (the P palm points on the last, vectorised axis) and the minimum taken on
    squared distances before the one sqrt: ~5× faster than norms over a trailing xyz axis of length 3.
    The squares are summed in the order XLA's size-3 reduction uses, (x² + z²) + y², and sqrt is
    monotone, so the result is bitwise the distance ``min_p ‖tip − palm_p‖`` of ``jnp.linalg.norm``
    (tests/test_metrics.py checks this against that direct form).
    """
    tips = x_CxTx2x21x3[:, :, :, jnp.asarray(sk.TIPS)]  # (C, T, 2, 5, 3)
    palm = jnp.swapaxes(jnp.einsum("pj,nthjc->nthpc", palm_Px21, x_CxTx2x21x3), -1, -2)  # (C, T, 2, 3, P)

    def one(h):
        t, p = tips[:, :, h], palm[:, :, 1 - h]  # (C, T, 5, 3), (C, T, 3, P)
        sq = [jnp.square(t[..., k, None] - p[:, :, None, k, :]) for k in range(3)]  # (C, T, 5, P) each
        return jnp.sqrt(jnp.min((sq[0] + sq[2]) + sq[1], axis=-1))

    return jnp.stack([one(0), one(1)], axis=2)


def _chunked_tip_palm_min_dist(x_NxTx2x21x3: jax.Array, palm_Px21: jax.Array) -> jax.Array:
    """:func:`_tip_palm_min_dist` over chunks of clips (lax.map): the full (N, T, 2, P, 3) palm cloud and
    (N, T, 5, P) distances would not fit in cache; zero-padded rows are computed and dropped."""
    n = x_NxTx2x21x3.shape[0]
    c = max(1, min(CONTACT_CHUNK, n))
    k = -(-n // c)
    x = jnp.pad(x_NxTx2x21x3, [(0, k * c - n)] + [(0, 0)] * (x_NxTx2x21x3.ndim - 1))
    d = jax.lax.map(lambda xc: _tip_palm_min_dist(xc, palm_Px21), x.reshape(k, c, *x.shape[1:]))
    return d.reshape(k * c, *d.shape[2:])[:n]


@partial(jax.jit, static_argnames=("intra_m", "inter_m"))
def contact_labels(joints_NxTx2x21x3: jax.Array, palm_Px21: jax.Array, intra_m: float = 0.020,
                   inter_m: float = 0.025):
    """Per-sequence contact booleans (reference §5.4).

    intra (N, 8): hand × thumb tip vs index/middle/ring/pinky tip, < intra_m in ≥ 1 frame.
    inter (N, 10): left tips vs right palm cloud, then right tips vs left palm cloud, < inter_m.
    """
    x = joints_NxTx2x21x3
    tips = x[:, :, :, jnp.asarray(sk.TIPS)]  # (N, T, 2, 5, 3)
    d_intra = jnp.linalg.norm(tips[..., 1:, :] - tips[..., :1, :], axis=-1)  # (N, T, 2, 4)
    intra = jnp.any(d_intra < intra_m, axis=1).reshape(x.shape[0], 8)
    d_inter = _chunked_tip_palm_min_dist(x, palm_Px21)  # (N, T, 2, 5)
    inter = jnp.any(d_inter < inter_m, axis=1).reshape(x.shape[0], 10)
    return intra, inter


def contact_prf(pred_NxK, gt_NxK) -> dict[str, float]:
    """Micro-averaged precision/recall/F1 over all sequences and labels (reference §5.4)."""
    p, g = np.asarray(pred_NxK, bool), np.asarray(gt_NxK, bool)
    tp, fp, fn = float((p & g).sum()), float((p & ~g).sum()), float((~p & g).sum())
    prec = tp / (tp + fp + 1e-8)
    rec = tp / (tp + fn + 1e-8)
    return {"precision": prec, "recall": rec, "f1": 2 * prec * rec / (prec + rec + 1e-8)}


# ------------------------------------------------------------------------------------------------
# The neighbouring hand papers' metrics (issue 33): G-HTT's MPJPE-RA / MPJPE-PA and APD, BimArt's
# inter-hand penetration ("Pen 1cm") and contact feasibility.


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
    H = jnp.einsum("...ji,...jk->...ik", xc, yc)  # (B, 3, 3)
    U, S, Vt = jnp.linalg.svd(H)
    d = jnp.where(jnp.linalg.det(U) * jnp.linalg.det(Vt) < 0, -1.0, 1.0)  # det(V Uᵀ) = det(U) det(Vᵀ)
    D = jnp.stack([jnp.ones_like(d), jnp.ones_like(d), d], -1)  # (B, 3)
    R = jnp.einsum("...ji,...j,...kj->...ik", Vt, D, U)  # V D Uᵀ
    var = jnp.sum(xc**2, axis=(-2, -1))
    s = jnp.sum(S * D, -1) / jnp.where(var > 0, var, 1.0)
    return s[..., None, None] * jnp.einsum("...ij,...kj->...ki", R, xc) + my


MOTION_CHUNK = 50  # clips per lax.map step of the per-frame Procrustes, penetration and contact scans


def _chunked(fn, *xs_N):
    """``fn`` over chunks of MOTION_CHUNK clips of equally long leading axes (lax.map: the per-frame
    temporaries of 6,000 clips would not fit in cache); zero-padded rows are computed and dropped."""
    n = xs_N[0].shape[0]
    c = max(1, min(MOTION_CHUNK, n))
    k = -(-n // c)
    pad = lambda x: jnp.pad(x, [(0, k * c - n)] + [(0, 0)] * (x.ndim - 1)).reshape(k, c, *x.shape[1:])
    out = jax.lax.map(lambda a: fn(*a), tuple(pad(x) for x in xs_N))
    return jax.tree_util.tree_map(lambda o: o.reshape(k * c, *o.shape[2:])[:n], out)


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

    return 1000.0 * _chunked(one, pred_NxTx2x21x3, gt_NxTx2x21x3)


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


# Capsule radii (m) of the 20 bones of sk.BONES (parent → child), for inter-hand penetration. Each bone
# is a capsule around the segment between its joints; the radii are round numbers in the range of adult
# finger thickness as MANO's template hand has it (issue 33: ~8–10 mm finger radius, palm larger):
# finger breadths are ~18–20 mm at the proximal phalanx and ~14–16 mm at the distal one in hand
# anthropometry, and the palm at the metacarpals is ~25 mm thick. They are not fitted to meshes: a
# MANO mesh would give the real surface (BimArt §4 counts penetrating hand *vertices*), which this
# project does not carry. The palm is covered by the wrist → MCP (and wrist → thumb CMC) capsules.
CAPSULE_RADIUS_M = {"palm": 0.012, "thumb_metacarpal": 0.011, "proximal": 0.009, "middle": 0.008, "distal": 0.007}


def _bone_part(parent: int, child: int) -> str:
    chain = next(c for c in sk.CHAINS.values() if child in c)
    level = chain.index(child)  # 1: wrist → base, 2..4 along the finger
    if sk.JOINT_NAMES[chain[1]] == "thumb_cmc":  # thumb: wrist → CMC, metacarpal, proximal, distal
        return ("palm", "thumb_metacarpal", "proximal", "distal")[level - 1]
    return ("palm", "proximal", "middle", "distal")[level - 1]


BONE_RADII_M = np.array([CAPSULE_RADIUS_M[_bone_part(p, c)] for p, c in sk.BONES], np.float32)  # (20,)
_BONE_PARENT = np.array([p for p, _ in sk.BONES])
_BONE_CHILD = np.array([c for _, c in sk.BONES])
_BONE_IS_TIP = np.isin(_BONE_CHILD, sk.TIPS)


@jax.jit
def segment_distance(p1: jax.Array, q1: jax.Array, p2: jax.Array, q2: jax.Array) -> jax.Array:
    """Closest distance between segments [p1, q1] and [p2, q2] (…, 3) → (…), broadcasting.

    Ericson, Real-Time Collision Detection §5.1.9: the closest points minimise over (s, t) ∈ [0, 1]²;
    s is clamped from the unconstrained solution, t follows from s and is clamped, then s is recomputed
    for a clamped t. Parallel segments (a·e − b² = 0) start from s = 0; degenerate segments (points)
    are handled by the same clamps.
    """
    mv = lambda v: jnp.moveaxis(v, -1, 0)
    return _segment_distance_cm(*(mv(jnp.broadcast_to(v, jnp.broadcast_shapes(p1.shape, q1.shape, p2.shape, q2.shape)))
                                  for v in (p1, q1, p2, q2)))


def _segment_distance_cm(p1, q1, p2, q2) -> jax.Array:
    """:func:`segment_distance` with the xyz coordinates on the FIRST axis (3, …): the dot products are
    then sums of three whole arrays, not reductions over a trailing axis of length 3 (~5x slower on CPU,
    as in _tip_palm_min_dist)."""
    dot = lambda u, v: u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = dot(d1, d1), dot(d2, d2)
    b, c, f = dot(d1, d2), dot(d1, r), dot(d2, r)
    eps = 1e-12
    safe = lambda x: jnp.where(x > eps, x, 1.0)
    denom = a * e - b * b
    s = jnp.where(denom > eps * jnp.maximum(a * e, eps), jnp.clip((b * f - c * e) / safe(denom), 0.0, 1.0), 0.0)
    s = jnp.where(a > eps, s, 0.0)
    t = jnp.where(e > eps, (b * s + f) / safe(e), 0.0)
    s = jnp.where(t < 0.0, jnp.where(a > eps, jnp.clip(-c / safe(a), 0.0, 1.0), 0.0), s)
    s = jnp.where(t > 1.0, jnp.where(a > eps, jnp.clip((b - c) / safe(a), 0.0, 1.0), 0.0), s)
    t = jnp.clip(t, 0.0, 1.0)
    g = (p1 + d1 * s) - (p2 + d2 * t)
    return jnp.sqrt(dot(g, g))


@jax.jit
def capsule_penetration(p1, q1, r1, p2, q2, r2) -> jax.Array:
    """Overlap depth of two capsules (segment + radius), 0 when apart: max(0, r1 + r2 − dist(segments))."""
    return jnp.maximum(r1 + r2 - segment_distance(p1, q1, p2, q2), 0.0)


def hand_capsules(joints_Mx21x3: jax.Array, radii_20=BONE_RADII_M) -> tuple[jax.Array, jax.Array]:
    """Capsule segments (M, 20, 3) × 2 of one hand's bones. A fingertip joint lies on the skin (MANO's tip
    vertices), so a distal capsule ends its radius short of the tip: its rounded end touches the tip."""
    x = joints_Mx21x3
    p, q = x[..., _BONE_PARENT, :], x[..., _BONE_CHILD, :]
    d = q - p
    length = jnp.linalg.norm(d, axis=-1, keepdims=True)
    r = jnp.asarray(radii_20)[:, None]
    keep = jnp.where(length > 0, jnp.clip(length - r, 0.0, None) / jnp.where(length > 0, length, 1.0), 0.0)
    q = jnp.where(jnp.asarray(_BONE_IS_TIP)[:, None], p + d * keep, q)
    return p, q


@jax.jit
def interhand_penetration(joints_NxTx2x21x3: jax.Array, radii_20=BONE_RADII_M) -> jax.Array:
    """Per frame (N, T), m: the deepest overlap between any left-hand bone capsule and any right-hand one
    (:data:`CAPSULE_RADIUS_M`), 0 where the hands' capsules do not touch. BimArt's "Pen 1cm" (§4,
    "Evaluation Metrics") is the share of frames where this exceeds 1 cm."""
    r = jnp.asarray(radii_20, jnp.float32)

    def one(x_CxTx2x21x3):
        cm = lambda v: jnp.moveaxis(v, -1, 0)  # (3, C, T, 20)
        pl, ql = map(cm, hand_capsules(x_CxTx2x21x3[:, :, 0], r))
        pr, qr = map(cm, hand_capsules(x_CxTx2x21x3[:, :, 1], r))
        dist = _segment_distance_cm(pl[..., :, None], ql[..., :, None], pr[..., None, :], qr[..., None, :])
        return jnp.maximum(jnp.max(r[:, None] + r[None, :] - dist, axis=(-2, -1)), 0.0)  # (C, T)

    return _chunked(one, joints_NxTx2x21x3)


def penetration_stats(depth_NxT, threshold_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Per clip: % of frames penetrating deeper than ``threshold_m`` (BimArt's "Pen 1cm", %) and the
    mean over all frames of the per-frame depth (mm; frames without contact count 0)."""
    d = np.asarray(depth_NxT, np.float64)
    return 100.0 * (d > threshold_m).mean(1), 1000.0 * d.mean(1)


# Contact feasibility: the contacts a clip's interaction caption and hand captions name are the contact
# events of its structured record (data/events.py; the captioner never leaves out a contact, data/caption
# inter.py, hand.py). Each is one channel of a per-frame distance and a half-open frame range;
# a named contact is realised when the generated motion brings the pair within the project's contact
# threshold in at least one frame of that range (BimArt §4 "Con" asks the same of hand–object contact).
# Channels: 8 intra-hand thumb-tip pairs, 25 left × right tip pairs, 10 tip → other palm (mean of the
# k closest palm-cloud points, as the events measure it).
def _contact_channels() -> dict[tuple[str, str], int]:
    from handx_jax.data import events as evm

    keys = [(h, k) for h in ("left_hand_events", "right_hand_events") for k in evm._INTRA_KEYS]
    keys += [("finger_tip_contact", k) for k in evm._INTER_KEYS] + [("finger_palm_distance", k) for k in evm._FP_KEYS]
    return {k: i for i, k in enumerate(keys)}


CONTACT_CHANNELS = _contact_channels()  # (section, record key) → channel
N_CONTACT_CHANNELS = len(CONTACT_CHANNELS)  # 43


@dataclass(frozen=True)
class NamedContacts:
    """The E contacts named by N clips' records: clip index, channel, half-open [start, end)."""

    clip_E: np.ndarray
    channel_E: np.ndarray
    start_E: np.ndarray
    end_E: np.ndarray

    def __len__(self) -> int:
        return len(self.clip_E)


def named_contacts(records) -> NamedContacts:
    """The contact events of each clip's record (events.annotate layout, reference §6.3): tip–tip runs
    within and across hands, and the "contact" periods of the finger–palm series (the captioner's own
    reading, caption.inter.contact_periods). Palm–palm contact is not a tip contact and is not counted."""
    from handx_jax.data.caption.inter import contact_periods

    rows = []
    for n, rec in enumerate(records):
        T = int(rec["frame_count"])
        for h in ("left_hand_events", "right_hand_events"):
            for key, runs in rec[h].get("finger_tip_contact", {}).items():
                rows += [(n, CONTACT_CHANNELS[(h, key)], e["start"], e["end"]) for e in runs]
        rel = rec["two_hand_relationships"]
        for key, runs in rel.get("finger_tip_contact", {}).items():
            rows += [(n, CONTACT_CHANNELS[("finger_tip_contact", key)], e["start"], e["end"]) for e in runs]
        for key, evs in rel.get("finger_palm_distance", {}).items():
            rows += [(n, CONTACT_CHANNELS[("finger_palm_distance", key)], s, e) for s, e in contact_periods(evs, T)]
    a = np.asarray(rows, np.int64).reshape(-1, 4)
    return NamedContacts(a[:, 0], a[:, 1], a[:, 2], a[:, 3])


def contact_thresholds() -> np.ndarray:
    """(43,) m: tip–tip below AnnotationConfig.tip_contact_m (Table A: 2 cm), tip–palm below the
    finger–palm "contact" state edge (2.5 cm), the thresholds that made the records' contact events."""
    from handx_jax.data import events as evm

    tip, palm = evm.AnnotationConfig().tip_contact_m, evm.FINGER_PALM.state_edges[0]
    return np.array([palm if sec == "finger_palm_distance" else tip for sec, _ in CONTACT_CHANNELS], np.float32)


@partial(jax.jit, static_argnames=("k",))
def contact_channel_distances(joints_NxTx2x21x3: jax.Array, palm_Px21: jax.Array, k: int = 5) -> jax.Array:
    """Per-frame distances (N, T, 43) m of the :data:`CONTACT_CHANNELS`, as features.py measures them:
    tip–tip, and tip → mean of the ``k`` closest points of the other hand's palm cloud."""
    def one(x):
        tips = x[:, :, :, jnp.asarray(sk.TIPS)]  # (C, T, 2, 5, 3) thumb..pinky
        intra = jnp.linalg.norm(tips[:, :, :, 1:] - tips[:, :, :, :1], axis=-1).reshape(*x.shape[:2], 8)
        inter = jnp.linalg.norm(tips[:, :, 0, :, None] - tips[:, :, 1, None, :], axis=-1).reshape(*x.shape[:2], 25)
        # Coordinate-major (xyz first), as in _tip_palm_min_dist: the k smallest of the squared distances,
        # then k square roots.
        palm = jnp.einsum("pj,cthjx->xcthp", palm_Px21, x)[:, :, :, ::-1]  # (3, C, T, 2, P): the OTHER hand
        tcm = jnp.moveaxis(tips, -1, 0)[..., None]  # (3, C, T, 2, 5, 1)
        sq = [jnp.square(tcm[i] - palm[i][..., None, :]) for i in range(3)]  # (C, T, 2, 5, P) each
        near = -jax.lax.top_k(-((sq[0] + sq[2]) + sq[1]), k)[0]
        fp = jnp.mean(jnp.sqrt(near), -1).reshape(*x.shape[:2], 10)
        return jnp.concatenate([intra, inter, fp], -1)

    return _chunked(one, joints_NxTx2x21x3)


@jax.jit
def _realised(dist_NxTxC, thr_C, clip_E, channel_E, start_E, end_E):
    d = dist_NxTxC[clip_E, :, channel_E]  # (E, T)
    t = jnp.arange(d.shape[1])
    inside = (t[None] >= start_E[:, None]) & (t[None] < end_E[:, None])
    return jnp.any(inside & (d < thr_C[channel_E][:, None]), axis=1)


def contact_feasibility_counts(joints_NxTx2x21x3, named: NamedContacts, palm_Px21,
                               k: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Per clip (N,): contacts named by its record and how many of them the motion realises."""
    n = joints_NxTx2x21x3.shape[0]
    named_N = np.bincount(named.clip_E, minlength=n).astype(np.float64)
    if not len(named):
        return np.zeros(n), named_N
    d = contact_channel_distances(jnp.asarray(joints_NxTx2x21x3, jnp.float32), jnp.asarray(palm_Px21), k)
    hit = np.asarray(_realised(d, jnp.asarray(contact_thresholds()), *(jnp.asarray(a) for a in (
        named.clip_E, named.channel_E, named.start_E, named.end_E))))
    return np.bincount(named.clip_E, weights=hit.astype(np.float64), minlength=n), named_N


# ------------------------------------------------------------------------------------------------
# Replications and confidence intervals

CI_GROUPS = "groups"
CI_BOOTSTRAP = "bootstrap_prompts"


# Quantities between the groups of one prompt: one value per prompt, never one per group.
BETWEEN_GROUPS = frozenset({"multimodality", "apd_left", "apd_right"})


def ci_method(metric: str, groups: int) -> str:
    """How the ± of ``metric`` is computed for ``groups`` generation groups (see the module docstring)."""
    return CI_GROUPS if groups > 1 and metric not in BETWEEN_GROUPS else CI_BOOTSTRAP


def mean_ci(values) -> tuple[float, float]:
    """Mean and the 95% Student-t half-width t_{0.975, n−1}·s/√n over n independent values (0 for n = 1)."""
    from scipy.stats import t as student_t

    v = np.asarray(values, np.float64)
    if len(v) < 2:
        return float(v.mean()), 0.0
    return float(v.mean()), float(student_t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v)))


def prompt_mean_ci(values_N, cfg: MetricConfig = MetricConfig()) -> tuple[float, float]:
    """Mean and bootstrap 95% half-width (prompts resampled, :func:`bootstrap_indices`) of a per-prompt
    quantity: the "bootstrap_prompts" interval (APD here; every row of the prediction benchmark)."""
    v = np.asarray(values_N, np.float64)
    n = len(v)
    return float(np.nanmean(v)), _per_prompt_ci(v, _counts(bootstrap_indices(n, cfg), n))


def bootstrap_indices(n: int, cfg: MetricConfig) -> np.ndarray:
    """(cfg.bootstrap, n) prompt indices drawn with replacement, fixed by the seed."""
    return np.random.default_rng([cfg.seed, 0xB0]).integers(0, n, size=(cfg.bootstrap, n))


def _counts(idx_BxN: np.ndarray, n: int) -> np.ndarray:
    """Multiplicity of each prompt in each resample (B, n): a per-prompt mean over a resample is counts @ v / n."""
    B = idx_BxN.shape[0]
    c = np.zeros((B, n), np.float64)
    np.add.at(c, (np.repeat(np.arange(B), idx_BxN.shape[1]), idx_BxN.reshape(-1)), 1.0)
    return c


def bootstrap_half_width(stats_B) -> float:
    """1.96 × the standard deviation of a statistic over its bootstrap resamples."""
    return float(1.96 * np.std(np.asarray(stats_B, np.float64), ddof=1)) if len(stats_B) > 1 else 0.0


@partial(jax.jit, static_argnames=("block",))
def _block_ranks(text_NxD, motion_NxD, perm_N, *, block: int):
    """Per prompt (in the original order): rank of its motion among its block's (R-Precision), the
    matched distance, and whether the prompt was in a complete block (the N mod block rest is dropped)."""
    n = text_NxD.shape[0]
    b = block if n >= block else n
    used = perm_N[: (n // b) * b]
    t = text_NxD[used].reshape(n // b, b, -1)
    m = motion_NxD[used].reshape(n // b, b, -1)
    d = jax.vmap(pairwise_dist)(t, m)
    diag = jnp.diagonal(d, axis1=1, axis2=2)
    closer, tied = _closer_and_tied(d, diag)
    closer_N = jnp.zeros(n, jnp.int32).at[used].set(closer.reshape(-1).astype(jnp.int32))
    tied_N = jnp.zeros(n, jnp.int32).at[used].set(tied.reshape(-1).astype(jnp.int32))
    dist_N = jnp.zeros(n, d.dtype).at[used].set(diag.reshape(-1))
    valid_N = jnp.zeros(n, bool).at[used].set(True)
    return (closer_N, tied_N), dist_N, valid_N


@partial(jax.jit, static_argnames=("block",))
def _replicated_ranks(text_NxD, gen_GxNxD, perms_RxN, *, block: int):
    """:func:`_block_ranks` for every replication (prompt order) and every group: (R, G, N) each."""
    per_group = jax.vmap(lambda m, p: _block_ranks(text_NxD, m, p, block=block), in_axes=(0, None))
    return jax.vmap(lambda p: per_group(gen_GxNxD, p))(perms_RxN)


@jax.jit
def _pair_dist(emb_NxD, i1_P, i2_P):
    """Distances of the pairs (P,): the summands of Diversity."""
    return jnp.linalg.norm(emb_NxD[i1_P] - emb_NxD[i2_P], axis=-1)


def resampled_pair_mean(emb_NxD, i1_P, i2_P, idx_BxN) -> np.ndarray:
    """Diversity (B,) of each resample: pair positions (i1, i2) point into the resampled prompt list, so
    resample b's pairs are (idx_b[i1], idx_b[i2]).

    Every such pair is a pair of the N prompts, so the N × N distances are computed once (float64, the
    expanded form |a|² + |b|² − 2a·b: one small matmul) and the B·P pair distances gathered from them,
    instead of B gathers of 2 × (P, D) embeddings. Same values as the direct norms up to float rounding.
    """
    e = np.asarray(emb_NxD, np.float64)
    sq = np.sum(e * e, -1)
    with _blas_single_thread():
        dist_NxN = np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2.0 * (e @ e.T), 0.0))
    idx = np.asarray(idx_BxN)
    return dist_NxN[idx[:, np.asarray(i1_P)], idx[:, np.asarray(i2_P)]].mean(1)


def _per_prompt_ci(values_N, counts_BxN) -> float:
    """Bootstrap half-width of the mean of a per-prompt quantity (NaN = no value for that prompt)."""
    v = np.asarray(values_N, np.float64)
    ok = np.isfinite(v)
    c = counts_BxN[:, ok]
    return bootstrap_half_width((c @ v[ok]) / np.maximum(c.sum(1), 1.0))


def replicate_embedding_metrics(text_NxD, gen_GxNxD, gt_NxD, cfg: MetricConfig = MetricConfig(),
                                timings: dict | None = None) -> dict:
    """R-Precision, MM-Dist, FID, Diversity (and MultiModality if G > 1) as (point value, 95% half-width).

    ``gen_GxNxD`` holds G generation groups for the same N prompts; pass the GT embeddings as the
    single group to get the "Ground Truth" row. Point values average the ``replications`` re-blockings
    (R-Precision, MM-Dist) and re-drawn pairs (Diversity, MultiModality) over all groups; intervals
    are over groups or a prompt bootstrap, as :func:`ci_method` says (module docstring). ``timings``, if
    given, receives the seconds of each part (rprec_mm_dist, fid, diversity, multimodality).
    """
    last = time.perf_counter()

    def lap(name):  # seconds since the previous lap, into ``timings``
        nonlocal last
        now = time.perf_counter()
        if timings is not None:
            timings[name] = timings.get(name, 0.0) + now - last
        last = now

    text = jnp.asarray(text_NxD, jnp.float32)
    gen = jnp.asarray(gen_GxNxD, jnp.float32)
    gt = np.asarray(gt_NxD, np.float64)
    G, N, _ = gen.shape
    R = cfg.replications
    if R < 1:
        raise ValueError(f"replications must be >= 1, got {R}")
    rng = np.random.default_rng([cfg.seed, 0x4E])
    perms = np.stack([rng.permutation(N) for _ in range(R)])  # (R, N)
    boot = bootstrap_indices(N, cfg)
    counts = _counts(boot, N)

    def summarise(name, per_group_G, per_prompt_N=None, resampled_B=None):
        """Point value = mean over groups; the ± from the groups or the prompt bootstrap."""
        point = float(np.mean(per_group_G))
        if ci_method(name, G) == CI_GROUPS:
            return point, mean_ci(per_group_G)[1]
        if resampled_B is not None:
            return point, bootstrap_half_width(resampled_B)
        return point, _per_prompt_ci(per_prompt_N, counts)

    (closer_RxGxN, tied_RxGxN), dist_RxGxN, valid_RxGxN = jax.tree.map(
        np.asarray, _replicated_ranks(text, gen, jnp.asarray(perms), block=cfg.rprec_block))
    n_valid_GxN = valid_RxGxN.sum(0).astype(np.float64)
    out = {}
    for k in range(1, cfg.top_k + 1):
        hit_RxGxN = np.asarray(expected_hit(closer_RxGxN, tied_RxGxN, k), np.float64) * valid_RxGxN
        per_group = hit_RxGxN.sum((0, 2)) / valid_RxGxN.sum((0, 2))
        per_prompt = np.where(n_valid_GxN[0] > 0, hit_RxGxN[:, 0].sum(0) / np.maximum(n_valid_GxN[0], 1), np.nan)
        out[f"rprec_top{k}"] = summarise(f"rprec_top{k}", per_group, per_prompt)
    mm_group = (dist_RxGxN * valid_RxGxN).sum((0, 2)) / valid_RxGxN.sum((0, 2))
    mm_prompt = np.where(n_valid_GxN[0] > 0, (dist_RxGxN[:, 0] * valid_RxGxN[:, 0]).sum(0)
                         / np.maximum(n_valid_GxN[0], 1), np.nan)
    out["mm_dist"] = summarise("mm_dist", mm_group, mm_prompt)
    lap("rprec_mm_dist")

    fids_G = [fid(gt, np.asarray(gen[g])) for g in range(G)]
    fid_boot = None
    if ci_method("fid", G) == CI_BOOTSTRAP:
        fid_boot = fid_resampled(gt, np.asarray(gen[0]), counts)
    out["fid"] = summarise("fid", fids_G, resampled_B=fid_boot)
    lap("fid")

    pairs = [diversity_indices(N, cfg.diversity_pairs, cfg.seed + r) for r in range(R)]
    i1, i2 = (jnp.asarray(np.concatenate(p)) for p in zip(*pairs))  # the R pair sets, (R·k,) each
    div_G = [float(jnp.mean(_pair_dist(gen[g], i1, i2))) for g in range(G)]
    div_boot = None
    if ci_method("diversity", G) == CI_BOOTSTRAP:
        div_boot = resampled_pair_mean(gen[0], i1, i2, boot)
    out["diversity"] = summarise("diversity", div_G, resampled_B=div_boot)
    lap("diversity")

    if G > 1:
        m = min(G - 1, cfg.multimodality_pairs)
        per_prompt = np.zeros(N)
        for r in range(R):
            rr = np.random.default_rng([cfg.seed, 0x33, r])
            g1, g2 = rr.choice(G, m, replace=False), rr.choice(G, m, replace=False)
            per_prompt += np.asarray(jnp.linalg.norm(gen[g1] - gen[g2], axis=-1)).mean(0) / R  # (N,)
        out["multimodality"] = (float(per_prompt.mean()), _per_prompt_ci(per_prompt, counts))
        lap("multimodality")
    return out


def replicate_motion_metrics(gen_GxNxTx2x21x3, gt_NxTx2x21x3, cfg: MetricConfig = MetricConfig(),
                             named: NamedContacts | None = None) -> dict:
    """MPJPE (also G-HTT's -RA and -PA per hand), acceleration, jitter, contact P/R/F1, inter-hand
    penetration and, given the contacts the prompts' records name (``named``), contact feasibility, as
    (point value, 95% half-width): the point is the mean over generation groups; the ± is over groups
    (G > 1) or a bootstrap over clips (G = 1). With G > 1, APD per hand over the first
    ``cfg.apd_samples`` groups (all for 0), its ± a bootstrap over prompts (a between-group quantity)."""
    gen = np.asarray(gen_GxNxTx2x21x3, np.float32)
    G, N = gen.shape[:2]
    # The per-clip programs run on N zero-padded to a multiple of MOTION_CHUNK, their padded rows dropped
    # (``[:N]``): each row is computed on its own, so the values are those of the unpadded call, and one
    # compiled program of each serves every N up to the next multiple (a test session, or a sweep's
    # evaluate stages, compile them once, not once per reference size: ~0.5-2 CPU-s each).
    n_pad = -(-N // MOTION_CHUNK) * MOTION_CHUNK - N
    pad = lambda a: np.pad(a, [(0, n_pad)] + [(0, 0)] * (a.ndim - 1))  # noqa: E731
    gt = jnp.asarray(pad(np.asarray(gt_NxTx2x21x3, np.float32)))
    W = jnp.asarray(palm_barycentric(cfg.palm_points, cfg.seed))
    gt_intra, gt_inter = (np.asarray(a, bool)[:N] for a in contact_labels(gt, W, cfg.intra_contact_m,
                                                                          cfg.inter_contact_m))
    rows, per_clip = [], []
    for g in range(G):
        x = jnp.asarray(pad(gen[g]))
        intra, inter = (np.asarray(a, bool)[:N] for a in contact_labels(x, W, cfg.intra_contact_m,
                                                                        cfg.inter_contact_m))
        acc, jit_ = acceleration_jitter(x)
        clip = {"mpjpe": np.asarray(mpjpe_mm(x, gt, cfg.mpjpe_root), np.float64),
                "acceleration": np.asarray(acc, np.float64), "jitter": np.asarray(jit_, np.float64)}
        for name, v in (("ra", mpjpe_ra_mm(x, gt)), ("pa", mpjpe_pa_mm(x, gt))):
            v = np.asarray(v, np.float64)
            clip[f"mpjpe_{name}_left"], clip[f"mpjpe_{name}_right"] = v[:, 0], v[:, 1]
        clip["pen_1cm"], clip["pen_depth"] = penetration_stats(interhand_penetration(x), cfg.pen_threshold_m)
        if named is not None and len(named):
            clip["cf_hit"], clip["cf_named"] = contact_feasibility_counts(x, named, W)
        clip = {k: v[:N] for k, v in clip.items()}
        # Per-clip TP/FP/FN: contact P/R/F1 are micro-averaged, so a resample sums its clips' counts.
        for scope, p, q in (("intra", intra, gt_intra), ("inter", inter, gt_inter)):
            clip[f"tp_{scope}"] = (p & q).sum(1).astype(np.float64)
            clip[f"fp_{scope}"] = (p & ~q).sum(1).astype(np.float64)
            clip[f"fn_{scope}"] = (~p & q).sum(1).astype(np.float64)
        per_clip.append(clip)
        rows.append(_motion_row({k: v.sum() if _is_count(k) else v.mean() for k, v in clip.items()}))
    counts = _counts(bootstrap_indices(N, cfg), N)  # (B, N)
    if G > 1:
        out = {k: mean_ci([r[k] for r in rows]) for k in rows[0]}
        K = G if cfg.apd_samples == 0 else cfg.apd_samples
        if not 2 <= K <= G:
            raise ValueError(f"APD over {K} samples per prompt needs 2 <= K <= {G} (the groups given)")
        apd_Nx2 = apd_mm(np.pad(gen[:K], [(0, 0), (0, n_pad)] + [(0, 0)] * (gen.ndim - 2)))[:N]
        for h, side in enumerate(("left", "right")):
            out[f"apd_{side}"] = (float(apd_Nx2[:, h].mean()), _per_prompt_ci(apd_Nx2[:, h], counts))
        return out
    resampled = _motion_row({k: counts @ v / (1.0 if _is_count(k) else N) for k, v in per_clip[0].items()})
    return {k: (float(rows[0][k]), bootstrap_half_width(np.asarray(resampled[k])[np.isfinite(resampled[k])]))
            for k in rows[0]}


def _is_count(key: str) -> bool:
    return key[:3] in ("tp_", "fp_", "fn_", "cf_")


def _prf(tp, fp, fn):
    """Micro-averaged precision/recall/F1 from summed counts (reference §5.4, as :func:`contact_prf`)."""
    prec = tp / (tp + fp + 1e-8)
    rec = tp / (tp + fn + 1e-8)
    return prec, rec, 2 * prec * rec / (prec + rec + 1e-8)


def _motion_row(m: dict) -> dict:
    """Metric values from per-group means (mpjpe, acceleration, jitter) and summed contact counts."""
    row = {k: m[k] for k in ("mpjpe", "acceleration", "jitter", "mpjpe_ra_left", "mpjpe_ra_right", "mpjpe_pa_left",
                             "mpjpe_pa_right", "pen_1cm", "pen_depth")}
    for scope in ("intra", "inter"):
        p, r, f = _prf(m[f"tp_{scope}"], m[f"fp_{scope}"], m[f"fn_{scope}"])
        row.update({f"contact_precision_{scope}": p, f"contact_recall_{scope}": r, f"contact_f1_{scope}": f})
    if "cf_named" in m:  # realised / named over the clips (a resample with none named has no value)
        named = np.asarray(m["cf_named"], np.float64)
        row["contact_feasibility"] = np.where(named > 0, m["cf_hit"] / np.where(named > 0, named, 1.0), np.nan)
    return {k: (float(v) if np.ndim(v) == 0 else v) for k, v in row.items()}
