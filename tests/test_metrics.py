import math

import jax.numpy as jnp
import numpy as np
import pytest

from handx_jax import metrics as M
from handx_jax import skeleton as sk
from handx_jax.metrics import embedding, motion
from handx_jax.metrics.intervals import resample_counts


def test_fid_zero_for_same_set_and_monotone_in_shift():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(500, 16))
    assert M.fid(a, a) == pytest.approx(0.0, abs=1e-6)
    vals = [M.fid(a, a + s) for s in (0.0, 0.1, 0.3, 1.0, 3.0)]
    assert all(x < y for x, y in zip(vals, vals[1:]))
    # Known value: pure mean shift by s in every dim → FID = D·s².
    assert vals[3] == pytest.approx(16 * 1.0, rel=1e-6)
    # Known value: scaling covariance by c² (isotropic) adds D·(1 − c)² for identity covariance.
    b = rng.normal(size=(200000, 4))
    assert M.fid(b, 2 * b) == pytest.approx(4 * (1 - 2) ** 2, rel=2e-2)


def _fid_sqrtm_reference(a, b):
    """The textbook FID (float64, scipy.linalg.sqrtm of the non-symmetric product Σ1Σ2)."""
    import scipy.linalg

    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    s1, s2 = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
    covmean = scipy.linalg.sqrtm(s1 @ s2)
    return float(np.sum((a.mean(0) - b.mean(0)) ** 2) + np.trace(s1) + np.trace(s2) - 2.0 * np.trace(covmean).real)


def test_fid_matches_the_scipy_sqrtm_formula():
    rng = np.random.default_rng(4)
    mix = rng.normal(size=(12, 12))
    a = rng.normal(size=(300, 12)) @ mix
    b = 0.3 + rng.normal(size=(250, 12)) @ (mix + 0.5 * rng.normal(size=(12, 12)))
    assert M.fid(a, b) == pytest.approx(_fid_sqrtm_reference(a, b), rel=1e-9)
    # Singular Σ1 (fewer samples than dimensions): no Cholesky factor, the eigh square root is used.
    a_few = a[:8]
    s1, s2 = np.cov(a_few, rowvar=False), np.cov(b, rowvar=False)
    ev = np.clip(np.linalg.eigvals(s1 @ s2).real, 0, None)
    want = np.sum((a_few.mean(0) - b.mean(0)) ** 2) + np.trace(s1) + np.trace(s2) - 2 * np.sqrt(ev).sum()
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(s1)
    assert M.fid(a_few, b) == pytest.approx(want, rel=1e-6)


def test_fid_bootstrap_equals_fid_of_each_explicit_resample():
    """The weighted-Gram bootstrap (counts, one matmul, Cholesky + eigvalsh) gives, for the same resample
    indices, the values of the straightforward computation: gather the rows, np.cov, scipy sqrtm."""
    rng = np.random.default_rng(5)
    n, d = 80, 6
    a = 2.0 + rng.normal(size=(n, d)) @ rng.normal(size=(d, d))
    b = a + 0.5 * rng.normal(size=(n, d)) + 0.1
    idx = M.bootstrap_indices(n, M.MetricConfig(bootstrap=25))
    counts = resample_counts(idx, n)
    mu, cov = M.resampled_moments(a, counts)
    np.testing.assert_allclose(mu, np.stack([a[i].mean(0) for i in idx]), rtol=1e-12, atol=1e-12)
    # The Gram correction is a float32 matmul on top of the exact float64 full-sample Gram (metrics.py):
    # agreement to ~1e-8 of the covariance's scale, far below float32's own 6e-8 per value.
    want_cov = np.stack([np.cov(a[i], rowvar=False) for i in idx])
    np.testing.assert_allclose(cov, want_cov, rtol=0, atol=1e-7 * np.abs(want_cov).max())
    want = [max(_fid_sqrtm_reference(a[i], b[i]), 0.0) for i in idx]
    # FID is Tr Σ1 + Tr Σ2 − 2 Tr sqrt(Σ1Σ2) (+ the mean term): its rounding error scales with the traces.
    scale = np.trace(np.cov(a, rowvar=False)) + np.trace(np.cov(b, rowvar=False))
    np.testing.assert_allclose(M.fid_resampled(a, b, counts), want, rtol=0, atol=1e-7 * scale)
    # Diversity's resamples: the gathered N × N distances equal the direct norms of the resampled pairs.
    i1, i2 = M.diversity_indices(n, 30, 0)
    direct = [np.mean(np.linalg.norm(a[i[i1]] - a[i[i2]], axis=-1)) for i in idx]
    np.testing.assert_allclose(M.resampled_pair_mean(a, i1, i2, idx), direct, rtol=1e-9)


def test_blas_single_thread_restores_the_thread_count():
    fns = embedding._openblas_threads()
    if fns is None:
        pytest.skip("no bundled OpenBLAS found")  # the context manager is then a no-op
    before = fns[0]()
    with embedding._blas_single_thread():
        assert fns[0]() == 1
    assert fns[0]() == before


def test_r_precision_perfect_and_random():
    rng = np.random.default_rng(1)
    e = rng.normal(size=(320, 8)).astype(np.float32)
    hits, mm = M.r_precision(jnp.asarray(e), jnp.asarray(e), block=32, top_k=3)
    np.testing.assert_allclose(hits, [1, 1, 1])
    assert float(mm) == pytest.approx(0.0, abs=1e-3)
    # Random: expected k/32; std of the mean over n = 32·nb items is sqrt(p(1-p)/n).
    n = 32 * 300
    t = rng.normal(size=(n, 8)).astype(np.float32)
    m = rng.normal(size=(n, 8)).astype(np.float32)
    hits, _ = M.r_precision(jnp.asarray(t), jnp.asarray(m), block=32, top_k=3)
    for k in (1, 2, 3):
        p = k / 32
        assert abs(float(hits[k - 1]) - p) < 4 * math.sqrt(p * (1 - p) / n)


def test_r_precision_known_ranking_and_small_n():
    # 3 items on a line: text i at position i, motion i at position i + offset.
    t = jnp.asarray([[0.0], [1.0], [2.0]])
    m = jnp.asarray([[0.6], [1.0], [2.0]])  # motion 0 is closer to text 1 than text 0 is... per-row
    hits, mm = M.r_precision(t, m, block=32, top_k=2)
    # Row 0: d = [0.6, 1, 2] → rank 0. Row 1: d = [0.4, 0, 1] → rank 0. Row 2: d = [1.4, 1, 0] → 0.
    np.testing.assert_allclose(hits, [1, 1])
    assert float(mm) == pytest.approx(0.2, abs=1e-6)
    m2 = jnp.asarray([[1.2], [1.0], [2.0]])  # now row 0 sees motion 1 closer (1.0 < 1.2)
    hits, _ = M.r_precision(t, m2, block=32, top_k=2)
    np.testing.assert_allclose(hits, [2 / 3, 1])


def test_diversity_and_multimodality():
    e = np.tile(np.arange(4.0), (50, 1))
    i1, i2 = M.diversity_indices(50, 300, 0)
    assert len(i1) == 49
    assert float(M.diversity(jnp.asarray(e), jnp.asarray(i1), jnp.asarray(i2))) == 0.0
    g = jnp.asarray(np.random.default_rng(0).normal(size=(10, 4, 3)))
    same = jnp.repeat(g[:, :1], 4, axis=1)
    assert float(M.multimodality(same, jnp.asarray([0, 1]), jnp.asarray([2, 3]))) == 0.0


def _hand_pair():
    """Two flat hands 20 cm apart, fingers along +y."""
    h = np.zeros((21, 3), np.float32)
    for f, x0 in zip(sk.FINGER_NAMES, (-0.045, -0.022, 0.0, 0.022, 0.045)):  # tips 2.2 cm apart
        for s, j in enumerate(sk.CHAINS[f][1:], start=1):
            h[j] = [x0, 0.03 * s, 0.0]
    left, right = h.copy(), h.copy()
    left[:, 0] -= 0.1
    right[:, 0] += 0.1
    return np.stack([left, right])


def test_contact_prf_exact_on_built_sequences():
    base = np.repeat(_hand_pair()[None], 10, axis=0)  # (T, 2, 21, 3), no contacts
    pinch = base.copy()
    pinch[4:6, 0, 17] = pinch[4:6, 0, 16] + [0.005, 0, 0]  # left thumb–index pinch in 2 frames
    touch = base.copy()
    touch[:, 1] -= [0.2, 0.1, 0]  # right hand slid onto the left: its tips (y = 0.02) lie on the left palm
    W = jnp.asarray(M.palm_barycentric(100, 0))
    intra, inter = M.contact_labels(jnp.asarray(np.stack([base, pinch, touch])), W)
    intra, inter = np.asarray(intra), np.asarray(inter)
    assert intra[0].sum() == 0 and inter[0].sum() == 0
    assert intra[1].tolist() == [True] + [False] * 7  # left hand, thumb vs index only
    assert inter[2].tolist() == [False] * 5 + [True] * 5  # right tips on the left palm, not vice versa
    # Tips 2.2 cm apart are not an intra contact (threshold 2.0 cm); 2.2 cm tip-palm gaps would be.
    # Pred = [pinch, base, touch] vs GT = [pinch, pinch, touch] → intra: TP 1, FN 1, FP 0.
    pi, _ = M.contact_labels(jnp.asarray(np.stack([pinch, base, touch])), W)
    gi, _ = M.contact_labels(jnp.asarray(np.stack([pinch, pinch, touch])), W)
    prf = M.contact_prf(pi, gi)
    assert prf["precision"] == pytest.approx(1.0, abs=1e-6)
    assert prf["recall"] == pytest.approx(0.5, abs=1e-6)
    assert prf["f1"] == pytest.approx(2 / 3, abs=1e-6)


def test_contact_scan_matches_direct_norm_form():
    """The chunked, coordinate-major tip-to-palm scan gives the distances of the direct ``linalg.norm`` form
    (bitwise on XLA CPU; 1 ulp allowed) and the same labels, for N not a multiple of the chunk."""
    import jax

    rng = np.random.default_rng(3)
    n, T = 2 * M.CONTACT_CHUNK + 23, 12
    x = np.repeat(_hand_pair()[None, None], n, axis=0).repeat(T, axis=1)  # (N, T, 2, 21, 3)
    # slide the right hand over the left palm by a random offset per clip: tip–palm gaps straddle 2.5 cm
    x[:, :, 1] -= np.array([0.2, 0.1, 0.0], np.float32) + rng.normal(scale=0.02, size=(n, 1, 1, 3))
    x = (x + rng.normal(scale=0.003, size=x.shape)).astype(np.float32)
    W = jnp.asarray(M.palm_barycentric(100, 0))

    @jax.jit
    def direct(x_, W_):
        tips = x_[:, :, :, jnp.asarray(sk.TIPS)]
        palm = jnp.einsum("pj,nthjc->nthpc", W_, x_)
        d = [jnp.linalg.norm(tips[:, :, h, :, None] - palm[:, :, 1 - h, None], axis=-1).min(-1) for h in (0, 1)]
        return jnp.stack(d, axis=2)

    want = np.asarray(direct(jnp.asarray(x), W))
    got = np.asarray(jax.jit(motion._chunked_tip_palm_min_dist)(jnp.asarray(x), W))
    np.testing.assert_array_max_ulp(got, want, maxulp=1)
    _, inter = M.contact_labels(jnp.asarray(x), W)
    labels = np.any(want < 0.025, axis=1).reshape(n, 10)
    assert 0.1 < labels.mean() < 0.9
    np.testing.assert_array_equal(np.asarray(inter), labels)


def test_palm_samples_lie_in_palm_triangles():
    W = M.palm_barycentric(100, 3)
    assert W.shape == (100, 21) and np.allclose(W.sum(1), 1) and (W >= 0).all()
    assert set(np.flatnonzero(W.sum(0))) == {0, 13, 1, 4, 10, 7}
    np.testing.assert_array_equal(W, M.palm_barycentric(100, 3))


def test_mpjpe_and_accel():
    rng = np.random.default_rng(0)
    g = rng.normal(size=(3, 60, 2, 21, 3)).astype(np.float32)
    assert np.allclose(M.mpjpe_mm(g, g), 0)
    np.testing.assert_allclose(M.mpjpe_mm(g + np.array([0.01, 0, 0], np.float32), g), 10.0, rtol=1e-4)
    # A global offset disappears relative to the left wrist.
    np.testing.assert_allclose(M.mpjpe_mm(g + 0.01, g, root="left_wrist"), 0, atol=1e-3)
    t = np.arange(60, dtype=np.float32) / 30
    x = np.zeros((1, 60, 2, 21, 3), np.float32)
    x[..., 0] = (0.5 * 2.0 * t**2)[None, :, None, None]  # constant 2 m/s² along x
    acc, jit_ = M.acceleration_jitter(jnp.asarray(x))
    assert float(acc[0]) == pytest.approx(2.0, rel=1e-3) and float(jit_[0]) == pytest.approx(0.0, abs=1e-2)


def test_a_collapsed_generator_scores_chance_not_perfect():
    """Identical generated motions tie at the same distance from every text; counting only strictly closer
    motions made every text a hit (R-Precision 1.0 for a generator that ignores its text). With ties broken
    uniformly at random, the expected top-k is k / block exactly."""
    rng = np.random.default_rng(1)
    text = rng.normal(size=(64, 8)).astype(np.float32)
    same = np.tile(rng.normal(size=(1, 8)).astype(np.float32), (64, 1))
    hits, _ = M.r_precision(jnp.asarray(text), jnp.asarray(same), block=32, top_k=3)
    np.testing.assert_allclose(np.asarray(hits), [1 / 32, 2 / 32, 3 / 32], rtol=1e-6)
    row = M.replicate_embedding_metrics(text, same[None], text, M.MetricConfig(replications=3))
    for k in (1, 2, 3):
        assert row[f"rprec_top{k}"][0] == pytest.approx(k / 32, rel=1e-6)
    # two distinct motions, each repeated: a text's own motion ties with the 15 other copies of it in its block
    two = np.where(np.arange(64)[:, None] % 2 == 0, text[0], text[1]).astype(np.float32)
    t2 = two + 1e-3 * rng.normal(size=two.shape).astype(np.float32)  # each text nearest its own kind
    hits, _ = M.r_precision(jnp.asarray(t2), jnp.asarray(two), block=32, top_k=3)
    np.testing.assert_allclose(np.asarray(hits), [1 / 16, 2 / 16, 3 / 16], rtol=1e-6)


def test_replications_ground_truth_row_and_ci():
    rng = np.random.default_rng(0)
    text = rng.normal(size=(256, 8)).astype(np.float32)
    motion = text + 0.05 * rng.normal(size=text.shape).astype(np.float32)
    cfg = M.MetricConfig(replications=5)
    gt = M.replicate_embedding_metrics(text, motion[None], motion, cfg)
    assert gt["rprec_top1"][0] > 0.95 and gt["fid"] == (pytest.approx(0.0, abs=1e-5), pytest.approx(0.0, abs=1e-5))
    noisy = M.replicate_embedding_metrics(text, (motion + rng.normal(size=text.shape))[None], motion, cfg)
    assert noisy["rprec_top1"][0] < gt["rprec_top1"][0] and noisy["fid"][0] > 1.0
    # Student-t 95% half-width over independent values: t_{0.975, 1} = 12.706 for two values
    assert M.mean_ci([1.0, 3.0]) == (2.0, pytest.approx(12.7062047 * math.sqrt(2) / math.sqrt(2)))
    assert M.mean_ci([4.0]) == (4.0, 0.0)


def test_ci_is_over_independent_values_and_named():
    """Issue 14.2: FID's ± was computed over the G group values repeated R/G times (0 for one group,
    shrinking with R). Now: over the groups themselves when G > 1, else a prompt bootstrap; neither
    depends on the number of re-blockings R."""
    rng = np.random.default_rng(1)
    N, G = 300, 4
    text = rng.normal(size=(N, 8)).astype(np.float32)
    gen = (text[None] + 0.7 * rng.normal(size=(G, N, 8))).astype(np.float32)
    few, many = (M.replicate_embedding_metrics(text, gen, text, M.MetricConfig(replications=R)) for R in (4, 20))
    fids = [M.fid(text, gen[g]) for g in range(G)]
    assert few["fid"] == pytest.approx(M.mean_ci(fids)) and many["fid"] == pytest.approx(M.mean_ci(fids))
    one = [M.replicate_embedding_metrics(text, gen[:1], text, M.MetricConfig(replications=R)) for R in (1, 20)]
    assert one[0]["fid"][1] > 0.05 and one[0]["fid"] == one[1]["fid"]  # bootstrap over prompts, not re-blockings
    assert M.ci_method("fid", 1) == M.ci_method("rprec_top1", 1) == "bootstrap_prompts"
    assert M.ci_method("fid", G) == M.ci_method("mpjpe", G) == "groups"
    assert M.ci_method("multimodality", G) == "bootstrap_prompts"  # a between-group quantity


def test_one_group_ci_matches_the_spread_over_independent_prompt_sets():
    """The ± of one group (prompt bootstrap) is 1.96 × the standard deviation the point value really has
    across independent draws of the prompts: R-Precision, MM-Dist, FID and Diversity. Ratio bounds allow
    for the ~12% error of a standard deviation estimated from 40 draws."""
    rng = np.random.default_rng(2)
    cfg = M.MetricConfig(replications=5, rprec_block=32, bootstrap=200)
    points, widths = [], []
    for _ in range(40):
        text = rng.normal(size=(256, 8)).astype(np.float32)
        gen = (text + 1.0 * rng.normal(size=text.shape)).astype(np.float32)
        out = M.replicate_embedding_metrics(text, gen[None], text, cfg)
        keys = ("rprec_top1", "rprec_top3", "mm_dist", "fid", "diversity")
        points.append([out[k][0] for k in keys])
        widths.append([out[k][1] for k in keys])
    ratio = np.mean(widths, 0) / (1.96 * np.std(points, 0, ddof=1))
    assert np.all((ratio > 0.65) & (ratio < 1.5)), dict(zip(keys, ratio.round(2)))


def test_motion_metric_ci_groups_and_bootstrap():
    rng = np.random.default_rng(3)
    gt = (0.05 * rng.normal(size=(40, 12, 2, 21, 3))).astype(np.float32)
    gen = gt[None] + (0.01 * rng.normal(size=(3, 40, 12, 2, 21, 3))).astype(np.float32)
    per_group = [float(np.mean(M.mpjpe_mm(gen[g], gt))) for g in range(3)]
    out = M.replicate_motion_metrics(gen, gt, M.MetricConfig())
    assert out["mpjpe"] == pytest.approx(M.mean_ci(per_group), rel=1e-4)
    one = M.replicate_motion_metrics(gen[:1], gt, M.MetricConfig())
    per_clip = np.asarray(M.mpjpe_mm(gen[0], gt))
    assert one["mpjpe"][0] == pytest.approx(per_clip.mean(), rel=1e-5)
    # bootstrap of a mean ≈ the standard error 1.96·σ/√N (200 resamples: within 25%)
    assert one["mpjpe"][1] == pytest.approx(1.96 * per_clip.std() / math.sqrt(40), rel=0.25)
