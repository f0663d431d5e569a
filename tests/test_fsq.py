import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from handx_jax import representation as R
from handx_jax.models import fsq as Q
from tests import handmade_hands as hh

# XLA compiles are most of this file's CPU. The quantiser checks run each codebook's maths as one jitted
# program (eagerly, every op compiles for every shape: ~1 s a case). The model tests share the tokenizer
# fitted below and its (8, 20)-frame shapes, so its encode and decode programs compile once; and the fit runs
# the training loop's own programs (initial state, train step) at the shapes and settings of
# tests/test_ar_family.py's tokenizer run (the tiny preset one block deep, codebook 256, batches of 8
# 20-frame windows), so in one session they compile once for both files (~10 CPU-s each time).
CFG = dataclasses.replace(Q.PRESETS["tiny"], codebook=256, depth=1)
MODEL = Q.FSQTokenizer(CFG)
APPLY = jax.jit(MODEL.apply, static_argnames="method")


def _jit(fn):
    """``fn(x, levels, quantizer)`` compiled, the levels and quantiser static."""
    return jax.jit(fn, static_argnums=(1, 2))


def _grid_points(levels, quantizer):
    """(max L, d) codes whose column k runs over the Lk codes of dimension k (then repeats its last)."""
    digits = np.minimum(np.arange(max(levels))[:, None], np.asarray(levels) - 1)
    return _jit(Q.digits_to_code)(digits, levels, quantizer)


def _round_trip(idx, levels, quantizer):
    code = Q.index_to_code(idx, levels, quantizer)
    digits = Q.index_to_digits(idx, levels)
    return code, Q.code_to_index(code, levels, quantizer), digits, Q.digits_to_index(digits, levels)


@pytest.mark.parametrize("quantizer", Q.QUANTIZERS)
@pytest.mark.parametrize("codebook", sorted(Q.LEVELS))
def test_every_code_lies_on_its_grid(codebook, quantizer):
    levels = Q.levels_for(codebook)
    y = jnp.asarray(np.random.default_rng(0).normal(scale=4.0, size=(4096, len(levels))), jnp.float32)
    code, digits = _jit(Q.quantize)(y, levels, quantizer)
    L = np.asarray(levels)
    d = np.asarray(digits)
    assert d.min() >= 0 and np.all(d <= L - 1)
    assert np.all(d.min(0) == 0) and np.all(d.max(0) == L - 1)  # wide inputs reach both ends of each level
    np.testing.assert_allclose(code, _jit(Q.digits_to_code)(digits, levels, quantizer), atol=1e-6)
    grids = _grid_points(levels, quantizer)
    for k, Lk in enumerate(levels):  # every value is one of the Lk grid points of its dimension
        grid = np.unique(np.asarray(grids)[:, k])
        assert len(grid) == Lk
        assert np.abs(np.asarray(code)[:, k, None] - grid[None]).min(1).max() < 1e-6
    if quantizer == "fsq":  # §4.2: code = q/⌊L/2⌋ with q ∈ {−⌊L/2⌋..⌈L/2⌉−1}
        assert np.asarray(code).min() >= -1.0 and np.asarray(code).max() <= 1.0


@pytest.mark.parametrize("codebook,real", [(256, 240), (512, 512), (1024, 1000), (2048, 1920), (4096, 4375),
                                           (16384, 15360), (65536, 64000)])
def test_index_code_round_trip_every_codebook(codebook, real):
    levels = Q.levels_for(codebook)
    assert Q.real_codebook_size(codebook) == real
    idx = jnp.arange(real)
    for quantizer in Q.QUANTIZERS:
        code, back, digits, from_digits = _jit(_round_trip)(idx, levels, quantizer)
        assert len(np.unique(np.asarray(code), axis=0)) == real
        np.testing.assert_array_equal(back, idx)
    np.testing.assert_array_equal(from_digits, idx)
    # First dimension least significant (§4.2).
    np.testing.assert_array_equal(digits[1], [1] + [0] * (len(levels) - 1))
    np.testing.assert_array_equal(digits[levels[0]], [0, 1] + [0] * (len(levels) - 2))


@pytest.mark.parametrize("quantizer", Q.QUANTIZERS)
def test_straight_through_gradient_is_identity_inside_range(quantizer):
    levels = Q.levels_for(4096)
    b = jnp.linspace(0.01, 3.9, 40)
    np.testing.assert_array_equal(jax.jit(jax.grad(lambda x: Q._round_ste(x).sum()))(b), np.ones(40))
    # The quantiser's Jacobian equals that of the same map without rounding.
    y = jnp.asarray(np.random.default_rng(1).normal(size=(8, len(levels))), jnp.float32)
    smooth = lambda y: Q._to_code(Q.bounded(y, levels, quantizer), levels, quantizer)  # noqa: E731
    g_q = jax.jit(jax.grad(lambda y: (Q.quantize(y, levels, quantizer)[0] * jnp.arange(1.0, 6.0)).sum()))(y)
    g_s = jax.jit(jax.grad(lambda y: (smooth(y) * jnp.arange(1.0, 6.0)).sum()))(y)
    np.testing.assert_allclose(g_q, g_s, rtol=1e-6)
    assert np.all(np.asarray(g_q) != 0)


def test_paper_form_is_round_sigmoid():
    levels = (8, 5)
    y = jnp.asarray([[0.0, 0.0], [10.0, -10.0], [0.3, 0.7]])
    _, digits = Q.quantize(y, levels, "paper")
    sig = 1 / (1 + np.exp(-np.asarray(y)))
    np.testing.assert_array_equal(digits, np.round(sig * (np.asarray(levels) - 1)))


def _clip(T=16):
    """A left/right pair whose fingers bend and wrists travel and turn over time."""
    frames = []
    for t in range(T):
        r = hh.right_hand({("index", 1): 3 * t, ("middle", 2): 2 * t})
        a = np.radians(4 * t)
        rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        r = r @ rz.T + np.array([0.01 * t, 0.0, 0.002 * t])
        frames.append(hh.pair(hh.mirror(r), r))
    return np.stack(frames)


def test_tokenizer_shapes_and_encode_decode_agree(fitted_8):
    model, params = MODEL, fitted_8[-1]
    # Shapes from tracing alone (the compiled program has the traced shapes; compiling three more costs seconds).
    x60 = jax.ShapeDtypeStruct((2, 60, 288), jnp.float32)
    xhat, digits = jax.eval_shape(model.apply, params, x60)
    assert xhat.shape == x60.shape and digits.shape == (2, 30, 3)  # 60 frames → 30 tokens
    assert jax.eval_shape(functools.partial(model.apply, method=model.encode), params, x60).shape == (2, 30)
    x48 = jax.ShapeDtypeStruct((2, 48, 288), jnp.float32)
    assert jax.eval_shape(functools.partial(model.apply, method=model.encode), params, x48).shape == (2, 24)  # §4.3
    # Values, compiled as training and decoding run them, at the fitted tokenizer's shapes (8 clips, 20 frames).
    x = jnp.asarray(np.random.default_rng(0).normal(size=(8, 20, 288)), jnp.float32)
    xhat, digits = APPLY(params, x)
    assert xhat.shape == x.shape and digits.shape == (8, 10, 3)
    idx = APPLY(params, x, method=model.encode)
    np.testing.assert_array_equal(idx, Q.digits_to_index(digits, CFG.levels))
    np.testing.assert_allclose(APPLY(params, idx, method=model.decode), xhat, atol=1e-5)


def test_rotation_row_convention_and_losses_known_values():
    f = R.to_ar(_clip())[None].astype(np.float32)  # (1, T, 288)
    rot = R.rotation_6d_to_matrix(f[..., 6:18].reshape(1, -1, 2, 6))
    np.testing.assert_allclose(Q.rot6d_to_matrix(jnp.asarray(f[..., 6:18].reshape(1, -1, 2, 6))), rot, atol=1e-5)
    mean, std = np.zeros(288, np.float32), np.ones(288, np.float32)
    loss = jax.jit(Q.tokenizer_loss)  # one compile for the three calls (eager: seconds each)
    total, aux = loss(jnp.asarray(f), jnp.asarray(f), mean, std)
    floor = float(np.arccos(np.float32(1 - 1e-7)))  # the reference's clamp: identical rotations give this
    for k, v in aux.items():
        assert float(v) == pytest.approx(floor if k.startswith("l_geo") else 0.0, abs=2e-4), k
    # Turning the predicted left wrist frame by θ about its first local axis: geo = θ/2 (half the
    # hand-frames change), and the relative (frame-to-frame) term stays at its floor.
    theta = 0.3
    rx = np.array([[1, 0, 0], [0, np.cos(theta), -np.sin(theta)], [0, np.sin(theta), np.cos(theta)]])
    turned = rot.copy()
    turned[..., 0, :, :] = rx @ rot[..., 0, :, :]
    g = f.copy()
    g[..., 6:18] = R.matrix_to_rotation_6d(turned).reshape(1, -1, 12)
    _, aux = loss(jnp.asarray(g), jnp.asarray(f), mean, std)
    assert float(aux["l_geo"]) == pytest.approx(theta / 2, abs=1e-3)
    assert float(aux["l_geo_rel"]) == pytest.approx(floor, abs=1e-3)
    # A constant shift of one local coordinate: SmoothL1 of 0.1 on 1/288 of "all" and 1/120 of "pos".
    h = f.copy()
    h[..., 50] += 0.1
    _, aux = loss(jnp.asarray(h), jnp.asarray(f), mean, std)
    assert float(aux["l_all"]) == pytest.approx(0.005 / 288, rel=1e-3)
    assert float(aux["l_pos"]) == pytest.approx(0.005 / 120, rel=1e-3)
    assert float(aux["l_pos_acc"]) == pytest.approx(0.0, abs=1e-9)


def test_mpjpe_matches_recovered_joints():
    f = R.to_ar(_clip())
    rng = np.random.default_rng(0)
    g = f + rng.normal(scale=0.01, size=f.shape)
    ours = float(Q.mpjpe_mm(jnp.asarray(g[None], jnp.float32), jnp.asarray(f[None], jnp.float32)))
    jp, jg = R.ar_to_joints(g), R.ar_to_joints(f)
    rel = lambda j: j - j[..., :1, :]  # noqa: E731  per hand, relative to its wrist
    ref = 1000 * np.linalg.norm(rel(jp) - rel(jg), axis=-1).mean()
    assert ours == pytest.approx(ref, rel=1e-4)
    assert float(Q.mpjpe_mm(jnp.asarray(f[None]), jnp.asarray(f[None]))) == pytest.approx(0.0, abs=1e-4)


def test_codebook_stats_known_values():
    s = Q.codebook_stats(np.array([0, 1, 2, 3] * 5), 8)
    assert s == {"usage": 0.5, "perplexity": pytest.approx(4.0), "codes_used": 4}
    assert Q.codebook_stats(np.zeros(10, int), 512)["perplexity"] == pytest.approx(1.0)


def test_analytic_flops_match_xla():
    cfg = Q.FSQConfig(width=64)
    model = Q.FSQTokenizer(cfg)
    # the parameters' shapes are all XLA's cost analysis needs (compiling ``init`` would cost more than the test)
    params = jax.eval_shape(lambda r: Q.init_tokenizer(cfg, r)[1], jax.random.PRNGKey(0))
    x = jnp.zeros((1, 60, 288))
    cost = jax.jit(lambda p, x: model.apply(p, x)[0]).lower(params, x).compile().cost_analysis()
    xla = (cost[0] if isinstance(cost, list) else cost)["flops"]
    assert abs(Q.forward_flops(cfg) - xla) / xla < 0.10, (Q.forward_flops(cfg), xla)


# ------------------------------------------------------------------------------------------------
# A tokenizer that reconstructs hands (issue 30): it fits a few clips, and its decoder uses its codes.


@pytest.fixture(scope="module")
def fitted_8(tmp_path_factory):
    """The tokenizer (tiny preset one block deep, codebook 256) fitted by the family's training loop
    (``handx_jax.train.train``) to 8 clips of the 32-clip test corpus, their first 20 frames (10 tokens each)
    in one batch, with the family's default loss and optimiser (AdamW, clipping at 1), 200 steps at 3e-3 peak
    (20 warm-up, cosine): measured 0.23× the mean pose, the wrist orientation 0.24× (the 64-wide, three-block
    tokenizer in a scan of plain Adam steps: 0.10× in ~19 CPU-s, 10 of them compiling the scan; full 60-frame
    clips: 0.18× in 46 CPU-s). The loop evaluates the initial weights (step 0) and the fitted ones on the same
    8 clips."""
    from handx_jax import train as loop
    from handx_jax.dataset.format import Dataset
    from handx_jax.families import tokenizer as T
    from tests.diffusion_fixtures import make_dataset

    root = tmp_path_factory.mktemp("fsq8")
    ds = Dataset.open(make_dataset(root, joined=True))  # the AR tests' corpus
    norm = T._ar_norm(ds)
    x = norm.normalize(R.to_ar(np.asarray(ds.motion[:8], np.float64))).astype(np.float32)[:, :20]
    rows = []
    # The family's recipe (tokenizer.CPU_TRAIN) with test_ar_family.py's batch: the learning rate, warm-up and
    # length are traced arguments of the step (train.schedule_values), so its program is that run's.
    optim = dataclasses.replace(T.CPU_TRAIN.optim, lr=3e-3, warmup_steps=20)
    cfg = dataclasses.replace(T.CPU_TRAIN, steps=200, batch_size=8, log_every=200, ckpt_every=200, eval_every=0,
                              wandb="disabled", prefetch=0, optim=optim)
    out = loop.train(root / "run", loop.TrainSpec(
        init=lambda rng: Q.init_tokenizer(CFG, rng, x.shape[1])[1],
        loss=T.make_loss(MODEL, norm, T.TokenizerRunConfig().loss), get_batch=lambda idx: {"x": x},
        num_examples=8, cfg=cfg, config={"family": "tokenizer-test"}, evaluate=T.make_evaluate(MODEL, CFG, x, norm)),
        on_log=rows.append)
    before, after = (r for r in rows if "eval/mpjpe_mm" in r)
    assert (before["step"], after["step"]) == (0, 200)
    return norm, jnp.asarray(x), before, after, out["params"]


def test_tokenizer_fits_eight_clips_below_a_third_of_the_mean_pose(fitted_8):
    _, _, before, after, _ = fitted_8
    assert before["eval/mean_pose_mpjpe_mm"] == after["eval/mean_pose_mpjpe_mm"] > 20  # hands that move and turn
    assert after["eval/mpjpe_vs_mean_pose"] < 0.3, after
    assert after["eval/mpjpe_mm"] < 0.3 * before["eval/mpjpe_mm"]
    # Every part of the split improved, the orientation included (the reference's loss left it near the mean pose).
    for k in ("eval/fingers_mm", "eval/wrist_orient_mm", "eval/root_mm", "eval/global_mpjpe_mm"):
        assert after[k] < before[k], k
    assert after["eval/wrist_orient_mm"] < 0.3 * after["eval/mean_pose_mpjpe_mm"]


def test_decoder_uses_its_codes(fitted_8):
    """Other codes give other motion: each clip decoded from another clip's codes reconstructs far worse
    than from its own, and every clip's codes differ from the others'."""
    norm, x, _, _, params = fitted_8
    model, apply = MODEL, APPLY
    idx = apply(params, x, method=model.encode)
    assert len({tuple(np.asarray(r)) for r in idx}) == 8
    mean, scale = jnp.asarray(norm.mean), jnp.asarray(norm.std + np.float32(norm.eps))

    @jax.jit  # one program for the three code sets (eagerly, every op of the MPJPE compiles on its own)
    def mpjpe_of(codes):
        return Q.mpjpe_mm(model.apply(params, codes, method=model.decode) * scale + mean, x * scale + mean)

    mpjpe = lambda codes: float(mpjpe_of(codes))  # noqa: E731
    own, shuffled = mpjpe(idx), mpjpe(jnp.roll(idx, 1, axis=0))
    assert shuffled > 3 * own, (own, shuffled)
    const = jnp.full_like(idx, int(idx[0, 0]))
    assert mpjpe(const) > 3 * own


def test_dead_decoder_is_said_at_evaluation(fitted_8, capsys):
    """The collapse v8's `small` tokenizer hit at warm-up 100 (tokenizer.SMALL_TRAIN): the decoder's last ReLU
    negative on every channel, so the decoder puts out its output bias whatever the codes. The evaluation hook
    says so on stderr once past COLLAPSE_AFTER steps, and says nothing for the fitted tokenizer."""
    from handx_jax.families import tokenizer as T

    norm, x, _, _, params = fitted_8
    evaluate = T.make_evaluate(MODEL, CFG, np.asarray(x), norm)
    live = evaluate(params, None, T.COLLAPSE_AFTER)
    assert "warning" not in capsys.readouterr().err
    dead = jax.tree_util.tree_map(lambda a: a, params)
    dead["params"]["decoder"]["conv_mid"]["bias"] = jnp.full_like(dead["params"]["decoder"]["conv_mid"]["bias"], -1e4)
    row = evaluate(dead, None, T.COLLAPSE_AFTER)
    err = capsys.readouterr().err
    assert row["eval/mpjpe_vs_mean_pose"] > T.COLLAPSE_RATIO > live["eval/mpjpe_vs_mean_pose"], (row, live)
    assert f"tokenizer at step {T.COLLAPSE_AFTER} reconstructs no better than the mean pose" in err
    evaluate(dead, None, T.COLLAPSE_AFTER - 1)  # before the mark: early weights may still sit at the mean
    assert "warning" not in capsys.readouterr().err
