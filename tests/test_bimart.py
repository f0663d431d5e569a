"""BimArt's models (families/bimart, models/bimart.py): the guidance gradient against finite differences, the
per-hand unit step, refinement lowering its three energies on a perturbed ground-truth clip, FLOPs against XLA,
and the registry's refusals of the wrong task."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from handx_jax.families import check_task
from handx_jax.families.bimart import common as C
from handx_jax.families.bimart import physics as PH
from handx_jax.models import bimart as BM
from handx_jax.objects.features import feature_dim

from handx_jax.synthesis.hand import LIMITS_HI_16, LIMITS_LO_16

H_LIMITS = (LIMITS_LO_16, LIMITS_HI_16)
CFG = BM.BimArtConfig(BM.BlockConfig(1, 32, 2, 64), k=4, keypoints=6)


def _guidance_case(seed=0, B=1, F=3):
    rng = np.random.default_rng(seed)
    X = BM.motion_dim(CFG)
    x = rng.normal(size=(B, F, X))
    V = rng.normal(size=(B, F, 2, CFG.k, 3)) * 0.05
    target = rng.uniform(0.0, 0.05, size=(B, F, 2, 2, CFG.k))
    mean, std = rng.normal(size=X) * 0.02, np.full(X, 0.03)
    t0 = rng.normal(size=(B, 3)) * 0.01
    return x, target, V, mean, std, t0


def test_guidance_gradient_matches_finite_differences():
    with jax.enable_x64():
        x, target, V, mean, std, t0 = (jnp.asarray(a, jnp.float64) for a in _guidance_case())

        def E(x):
            return jnp.sum(PH.contact_energy_per_hand(x, target, V, mean, std, t0, CFG))

        g = np.asarray(jax.grad(E)(x))
        rng = np.random.default_rng(1)
        for _ in range(4):
            u = rng.normal(size=x.shape)
            h = 1e-6
            fd = (float(E(x + h * u)) - float(E(x - h * u))) / (2 * h)
            np.testing.assert_allclose(np.sum(g * u), fd, rtol=1e-5, atol=1e-12)
        # Eq. 5 by brute force: the distance of each mapped point to the hand's nearest surface keypoint.
        H, _ = PH.x_to_points(x, mean, std, t0, CFG)
        S = np.asarray(H)[..., BM.JOINTS:, :]
        c = np.asarray(PH.derived_contact(jnp.asarray(S), V))
        b, f, h_, p, k = 0, 2, 1, 0, 3
        ref = min(np.linalg.norm(np.asarray(V)[b, f, p, k] - s) for s in S[b, f, h_])
        assert abs(c[b, f, h_, p, k] - ref) < 1e-9


def test_guidance_step_is_per_hand_and_unit():
    x, target, V, mean, std, t0 = (jnp.asarray(a, jnp.float32) for a in _guidance_case(seed=2, B=2))
    length = 0.05
    y = PH.contact_guide(x, target, V, mean, std, t0, CFG, length)
    for hand in range(2):
        rows_x, rows_y = PH.hand_rows(x), PH.hand_rows(y)
        for b in range(2):
            step = float(jnp.linalg.norm(rows_y[2 * b + hand] - rows_x[2 * b + hand]))
            e = PH.contact_energy_per_hand(x, target, V, mean, std, t0, CFG)[b, hand]
            assert e > 0
            assert step <= length + 1e-5 and step > 0.5 * min(length, 1e-3)
    # One hand's target met exactly → that hand's rows are left unchanged, the other hand's move.
    H, _ = PH.x_to_points(x, mean, std, t0, CFG)
    exact = PH.derived_contact(H[..., BM.JOINTS:, :], V)
    met = target.at[:, :, 0].set(exact[:, :, 0])
    y = PH.contact_guide(x, met, V, mean, std, t0, CFG, length)
    r = PH.hand_rows(y) - PH.hand_rows(x)
    assert float(jnp.abs(r[0::2]).max()) == 0.0 and float(jnp.abs(r[1::2]).max()) > 0


def test_flops_match_xla():
    for kind in ("contact", "motion"):
        p = jax.eval_shape(lambda k: BM.init(k, CFG, kind), jax.random.PRNGKey(0))
        S = jax.ShapeDtypeStruct
        X = BM.contact_dim(CFG) if kind == "contact" else BM.motion_dim(CFG)
        args = (p, S((1, 60, X), jnp.float32), S((1,), jnp.int32), S((1, 60, feature_dim(CFG.k)), jnp.float32),
                S((1, 60, BM.contact_dim(CFG)), jnp.float32), S((1,), bool))

        def f(p, x, t, o, c, n):
            return BM.denoise(p, CFG, x, t, o, *((c, n) if kind == "motion" else ()))
        ca = jax.jit(f).lower(*args).compile().cost_analysis()
        xla = (ca[0] if isinstance(ca, list) else ca)["flops"]
        assert abs(BM.forward_flops(CFG, kind) / xla - 1) < 0.1, (kind, BM.forward_flops(CFG, kind), xla)
    n = BM.param_count(BM.PRESETS["paper"], "motion")["params"]
    assert 2.5e7 < n < 3.5e7  # 8 layers x 512 wide: ~25M in the encoder, plus the in/out and condition MLPs


def test_wrong_task_refused_in_one_line(tmp_path, capsys):
    import json

    from handx_jax.cli import main

    for fam, task in (("bimart", "text2motion"), ("diffusion", "object2motion"), ("bimart-contact", "object2motion")):
        with pytest.raises(ValueError) as e:
            check_task(fam, task)
        assert "\n" not in str(e.value) and fam in str(e.value)
        run = tmp_path / fam
        run.mkdir()
        (run / "config.json").write_text(json.dumps({"family": fam}))
        extra = ["--left", "a", "--right", "b", "--interaction", "c"] if task == "text2motion" else ["--data", "D"]
        assert main(["generate", "--run", str(run), "--task", task, *extra, "--out", str(tmp_path / "g.npz")]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and f"family {fam} does not do --task {task}" in err
    check_task("bimart", "object2motion")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    from handx_jax.synthesis.object_build import ObjectBuildConfig, build_object_corpus
    from handx_jax.synthesis.object_motion import ObjectSynthConfig

    cfg = ObjectBuildConfig(clips=1, seed=5, workers=1, bps_k=16, val_fraction=0.2, test_fraction=0.2,
                            synth=ObjectSynthConfig(chunk_size=2))
    return build_object_corpus(tmp_path_factory.mktemp("bimart") / "obj", cfg, progress=False)


def test_refinement_lowers_its_energies(corpus):
    """Eight held frames of a ground-truth clip with 1 mm of jitter on every joint and the hand nearer the object
    pushed 8 mm into it: the fit and refinement (Eq. 8-12, the paper's weights) lower the projection,
    penetration and acceleration energies, and the refined hand is a hand: every bone keeps one length over the
    clip (hand_fit's geometry is the clip's), within 0.05 mm."""
    from handx_jax.synthesis.object_build import clip_object

    cfg = BM.BimArtConfig(BM.BlockConfig(1, 32, 2, 64), k=16, keypoints=8)
    ds, ann = C.open_corpus(corpus)
    f = slice(26, 34)
    T = 8
    rng = np.random.default_rng(0)
    gt = np.asarray(ds.motion[0, f], np.float32)
    obj, states = clip_object(ann["objects"][0]), jnp.asarray(ann["object_state"][0, f], jnp.float32)
    H_gt = C.keypoints(jnp.asarray(gt), cfg)
    D_hat = np.asarray(C._nearest_vectors(obj, states, H_gt.reshape(T, -1, 3))).reshape(H_gt.shape)  # the true D
    noisy = gt + rng.normal(size=gt.shape).astype(np.float32) * 0.001
    d = np.linalg.norm(D_hat, axis=-1)                                                # (T, 2, P)
    h = int(d.min(-1).min(0).argmin())
    k = d[:, h].argmin(1)
    dk, near = d[np.arange(T), h, k], D_hat[np.arange(T), h, k]
    close = dk < 0.02
    assert close.sum() >= 4
    noisy[close, h] += (near * (1 + 0.008 / dk)[:, None])[close][:, None]            # 8 mm inside the object
    H_hat = C.keypoints(jnp.asarray(noisy), cfg)
    rc = PH.RefineConfig(fit_iters=100, iters=40, lr=1e-3)
    args = (H_hat, jnp.asarray(D_hat), obj, states, cfg)
    before = {k: float(v) for k, v in PH.energies_jit(jnp.asarray(noisy), *args).items()}
    out = PH.refine_jit(jnp.asarray(noisy), *args, rc)
    after = {k: float(v) for k, v in PH.energies_jit(out, *args).items()}
    assert before["pen"] > 1e-6, before
    for term, factor in (("proj", 0.9), ("pen", 0.95), ("acc", 0.5)):
        assert after[term] < factor * before[term], (term, before, after)
    from handx_jax.skeleton import bone_lengths

    bones = bone_lengths(np.asarray(out, np.float64))                                 # (T, 2, 20)
    assert np.ptp(bones, axis=0).max() < 5e-5 and np.ptp(bone_lengths(noisy), axis=0).max() > 1e-3


def test_hand_fit_recovers_a_corpus_hand(corpus):
    """Eq. 8 on the ground truth: the corpus's hands are made by synthesis/hand.py's forward kinematics, so the
    parametric hand (hand_fit: closed-form start from the palm, then Adam on geometry and pose) fits a clip's
    60 frames of both hands to within a millimetre; the closed-form start alone is ~2 cm off (angles mid-range)."""
    from handx_jax.families.bimart import hand_fit as HF

    ds, _ = C.open_corpus(corpus)
    J = jnp.asarray(ds.motion[0], jnp.float32)
    theta = HF.init(J)
    start = float(jnp.mean(jnp.linalg.norm(HF.joints(theta) - J, axis=-1)))

    @jax.jit
    def fit(theta):
        def loss(t):
            return jnp.mean(jnp.sqrt(jnp.sum((HF.joints(t) - J) ** 2, -1) + 1e-12))

        def step(c, _):
            t, s = c
            return HF.scaled_adam_step(s, t, jax.grad(loss)(t), HF.STEP_SCALE), None
        return jax.lax.scan(step, (theta, HF.adam_init(theta)), None, length=150)[0][0]

    err = np.linalg.norm(np.asarray(HF.joints(fit(theta))) - np.asarray(J), axis=-1)
    assert start > 0.005 and err.mean() < 1e-3 and err.max() < 4e-3, (start, err.mean(), err.max())
    lo, hi = HF.angles(theta).min(), HF.angles(theta).max()
    assert lo >= H_LIMITS[0].min() and hi <= H_LIMITS[1].max()


def test_object_scores_carry_a_bootstrap_over_clips(corpus):
    """`handx eval objects`' ± (evaluation/object_clips.score): the ground-truth clip twice, then beside a copy whose
    hands are lifted 0.5 m off the object. Two equal clips give every interval 0; the pair [GT, lifted] gives Con's
    per-clip values [100, 0], whose 95% half-width is 1.96 x the spread of their mean over the bootstrap's resamples
    (metrics.bootstrap_indices), computed here with numpy; its point value stays the mean over clips."""
    from handx_jax.evaluation import object_clips
    from handx_jax.metrics import MetricConfig, bootstrap_indices

    ds, ann = C.open_corpus(corpus)
    gt = np.asarray(ds.motion[0], np.float32)
    lifted = gt + np.float32([0.0, 0.0, 0.5])

    def gen(*joints):
        n = len(joints)
        return {"joints": np.stack(joints)[:, None], "object_state": np.repeat(ann["object_state"][:1], n, 0),
                "contact": np.repeat(np.asarray(ann["contact_map"][:1], np.float32)[:, None], n, 0),
                "bps_points": np.repeat(ann["bps_points"][:1], n, 0), "records": [ann["objects"][0]] * n}

    same = object_clips.score(gen(gt, gt))
    assert same["obj_con"] == same["obj_art"] == 100.0 and same["obj_pen_1cm"] == 0.0  # the corpus's physics
    assert all(same[f"{k}_ci"] == 0.0 for k in ("obj_con", "obj_art", "obj_pen_1cm", "obj_cm_cm")), same
    pair = object_clips.score(gen(gt, lifted))
    assert pair["obj_con"] == 50.0 and pair["clips"] == 2 and pair["samples"] == 1
    idx = bootstrap_indices(2, MetricConfig())
    means = np.array([100.0, 0.0])[idx].mean(1)
    assert pair["obj_con_ci"] == pytest.approx(1.96 * means.std(ddof=1), rel=1e-9)
    assert pair["obj_cm_cm_ci"] > 0 and np.isnan(pair["obj_mul_cm"])  # one sample: no Mul, and no interval for it
    assert "obj_mul_cm_ci" not in pair
