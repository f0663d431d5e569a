"""The metrics on evaluator embeddings (text ``T_NxD``, motion ``M_NxD``; reference §5.4, paper E.2):
R-Precision, MM-Dist, FID, Diversity and MultiModality, and the per-replication ranks and pair
distances :mod:`handx_jax.metrics.replicate` averages. Block orders and pairs are drawn from explicit
seeds (the reference's unseeded draws, §9.17, are not ported)."""

from __future__ import annotations

import contextlib
import functools
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np


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
    closer, tied = closer_and_tied(d, diag)
    hits = jnp.stack([jnp.mean(expected_hit(closer, tied, k)) for k in range(1, top_k + 1)])
    return hits, jnp.mean(diag)


def closer_and_tied(d_NBxBxB: jax.Array, diag_NBxB: jax.Array) -> tuple[jax.Array, jax.Array]:
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

    Resample b holds row n ``counts[b, n]`` times (its multiplicities, :func:`resample_counts`), so with
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
    closer, tied = closer_and_tied(d, diag)
    closer_N = jnp.zeros(n, jnp.int32).at[used].set(closer.reshape(-1).astype(jnp.int32))
    tied_N = jnp.zeros(n, jnp.int32).at[used].set(tied.reshape(-1).astype(jnp.int32))
    dist_N = jnp.zeros(n, d.dtype).at[used].set(diag.reshape(-1))
    valid_N = jnp.zeros(n, bool).at[used].set(True)
    return (closer_N, tied_N), dist_N, valid_N


@partial(jax.jit, static_argnames=("block",))
def replicated_ranks(text_NxD, gen_GxNxD, perms_RxN, *, block: int):
    """:func:`_block_ranks` for every replication (prompt order) and every group: (R, G, N) each."""
    per_group = jax.vmap(lambda m, p: _block_ranks(text_NxD, m, p, block=block), in_axes=(0, None))
    return jax.vmap(lambda p: per_group(gen_GxNxD, p))(perms_RxN)


@jax.jit
def pair_distances(emb_NxD, i1_P, i2_P):
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

