"""Sampler exactness on a Gaussian toy, masked partial denoising, and the guidance dropout (issue 14.1, 14.3).

The toy: every coordinate of x0 is N(0, VAR) and independent, so the exact x0 denoiser is closed-form,
E[x0 | x_t] = √ᾱ_t·VAR / (ᾱ_t·VAR + 1 − ᾱ_t) · x_t. An exact sampler driven by it must reproduce the
data variance; masked sampling must leave free joints with that variance and put constrained joints
(γ = 1) on the target.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from handx_jax.families.diffusion import process as D

VAR = 0.25
SCHED = D.cosine_schedule(1000)
B, F, J, C = 512, 4, 4, 2  # 12k free values: the variance's relative standard error is √(2/n) ≈ 1.3%
GAMMA = np.zeros((F, J), np.float32)
GAMMA[:, 0] = 1.0  # joint 0 fully constrained (as the wrist or reaction tasks), joints 1..3 free
TARGET = jnp.asarray(np.random.default_rng(0).normal(size=(B, F, J, C)) * 0.5, jnp.float32)


def exact_denoiser(x, t_B, uncond_B):
    a = jnp.asarray(SCHED.alphas_cumprod, jnp.float32)[t_B][:, None, None, None]
    return jnp.sqrt(a) * VAR / (a * VAR + 1 - a) * x


def _sample(blend, sampler, masked, gamma=GAMMA, denoise=exact_denoiser, guidance=1.0, sched=SCHED, batch=B):
    cfg = D.DiffusionConfig(blend=blend, p_hard=1.0)
    kw = dict(target=TARGET[:batch], gamma_FxJ=gamma) if masked else {}
    fn = jax.jit(lambda k: D.sample(denoise, sched, (batch, F, J, C), k, cfg, sampler=sampler, steps=50,
                                    guidance=guidance, **kw))
    return np.asarray(fn(jax.random.PRNGKey(0)))


@pytest.mark.parametrize("blend", ["x0", "xt"])
def test_masked_ddpm_keeps_free_joints_exact_and_hits_the_target(blend):
    """DDPM-1000 and the masked sampler's free joints reach the data variance within 5% (the literal
    Eq. L gave 0.123 for 0.25: it re-noises x̂0 with fresh noise and forgets x_t); constrained joints
    end exactly on the target."""
    plain = _sample(blend, "ddpm", masked=False)
    assert abs(plain.var() / VAR - 1) < 0.05, plain.var()
    out = _sample(blend, "ddpm", masked=True)
    free = out[:, :, 1:]
    assert abs(free.var() / VAR - 1) < 0.05, free.var()
    assert abs(free.mean()) < 0.02
    np.testing.assert_array_equal(out[:, :, 0], np.asarray(TARGET)[:, :, 0])


def test_literal_eq_l_is_kept_as_an_option_and_loses_variance():
    out = _sample("x0_renoise", "ddpm", masked=True)
    assert 0.4 < out[:, :, 1:].var() / VAR < 0.6  # measured 0.123 / 0.25
    np.testing.assert_array_equal(out[:, :, 0], np.asarray(TARGET)[:, :, 0])


def _toy_cfg_denoiser(x, t_B, uncond_B):
    """Not the exact denoiser: a conditional offset makes guidance change the output."""
    return 0.5 * x + jnp.where(uncond_B, 0.0, 1.0)[:, None, None, None]


@pytest.mark.parametrize("sampler,blend", [("ddpm", "x0"), ("ddim", "x0"), ("ddpm", "xt"), ("ddim", "xt")])
def test_all_zero_mask_gives_exactly_the_unmasked_output(sampler, blend):
    zero = np.zeros((F, J), np.float32)
    kw = dict(denoise=_toy_cfg_denoiser, guidance=2.5, sched=D.cosine_schedule(100), batch=4)
    want = _sample(blend, sampler, masked=False, **kw)
    got = _sample(blend, sampler, masked=True, gamma=zero, **kw)
    np.testing.assert_array_equal(got, want)


def test_blend_names_are_checked():
    with pytest.raises(ValueError, match="blend must be one of x0, x0_renoise, xt"):
        D.DiffusionConfig(blend="eq_l")
    with pytest.raises(ValueError, match="joint_drop must be in"):
        D.DiffusionConfig(joint_drop=1.0)


def _drops_seen_by_make_loss(dcfg, batch_size):
    """The (B, 3) drop mask make_loss passes to the model, captured by a stand-in model."""
    from handx_jax.families.diffusion import make_loss

    seen = {}

    class Recorder:
        def apply(self, params, x_t, t, text, mask, drop, deterministic, rngs):
            seen["drop"] = drop
            return x_t

    batch = {"x0": jnp.zeros((batch_size, 2, 1, 4)), "text": jnp.zeros((batch_size, 3, 1, 1)),
             "mask": jnp.ones((batch_size, 3, 1), bool)}

    @jax.jit  # as the train step runs it: one program, not one compile per random op
    def drops(rng):
        make_loss(Recorder(), dcfg)(None, batch, rng, True)
        return seen["drop"]

    return np.asarray(drops(jax.random.PRNGKey(3)))


def test_joint_drop_rate_of_all_three_null():
    """P(all three null) = joint_drop + (1 − joint_drop)·cond_drop³ = 0.1009 at the defaults (0.001 with
    the per-branch drops alone); each branch alone is null with p = 0.1 + 0.9·0.1 = 0.19. Tolerances:
    4 binomial standard deviations over N samples."""
    N = 200_000
    cfg = D.DiffusionConfig(steps=10)
    drop = _drops_seen_by_make_loss(cfg, N)
    assert drop.shape == (N, 3) and drop.dtype == bool

    def close(rate, p):
        return abs(rate - p) < 4 * np.sqrt(p * (1 - p) / N)

    p_all = cfg.joint_drop + (1 - cfg.joint_drop) * cfg.cond_drop ** 3
    assert close(drop.all(1).mean(), p_all), drop.all(1).mean()
    p_one = cfg.joint_drop + (1 - cfg.joint_drop) * cfg.cond_drop
    for k in range(3):
        assert close(drop[:, k].mean(), p_one)
    # exactly two of three null happens only through the per-branch drops
    p_two = (1 - cfg.joint_drop) * 3 * cfg.cond_drop ** 2 * (1 - cfg.cond_drop)
    assert close((drop.sum(1) == 2).mean(), p_two)
    # joint_drop = 0 is the reference's independent per-branch dropout
    ref = jax.jit(D.cond_drop_mask, static_argnums=(1, 2))(jax.random.PRNGKey(1), N, D.DiffusionConfig(joint_drop=0.0))
    assert close(float(np.asarray(ref).all(1).mean()), 0.001)


def test_an_observation_trained_run_reads_its_observed_frames_clean_at_every_step():
    """diffusion.observe_prob > 0 (issue 41): the denoiser's input x_t holds the target exactly on γ = 1 entries at
    every step (as in training), and noise elsewhere; a run trained without it (the default) is given noised
    copies, as before. Soft-mask entries (γ < 1) are never replaced."""
    gamma = GAMMA.copy()
    gamma[:, 1] = 0.5  # a soft entry: never replaced
    seen = []

    def spy(x, t_B, uncond_B):
        jax.debug.callback(lambda v: seen.append(np.asarray(v)), x)
        return 0.5 * x

    for observe in (0.5, 0.0):
        seen.clear()
        cfg = D.DiffusionConfig(observe_prob=observe)
        out = D.sample(spy, D.cosine_schedule(100), (4, F, J, C), jax.random.PRNGKey(0), cfg, sampler="ddim",
                       steps=5, guidance=1.0, target=TARGET[:4], gamma_FxJ=gamma)
        assert len(seen) == 5
        tgt = np.asarray(TARGET[:4])
        np.testing.assert_array_equal(np.asarray(out)[:, :, 0], tgt[:, :, 0])  # kept either way
        clean = [np.array_equal(x[:, :, 0], tgt[:, :, 0]) for x in seen]
        assert clean == [observe > 0] * 5
        assert not any(np.allclose(x[:, :, 1], tgt[:, :, 1]) for x in seen)


def test_observation_frames_and_centring_on_them():
    """Training-time observation masks: a prefix of 1..observe_max frames on about observe_prob of the items, at
    least one frame left free; the clip re-centred so that the observed frames' mean wrist midpoint is the origin
    (the prediction task's placement), rows with no observation unchanged."""
    cfg = D.DiffusionConfig(observe_prob=0.75, observe_max=40)
    m = np.asarray(D.observation_frames(jax.random.PRNGKey(1), 4000, 60, cfg))
    n = m.sum(1)
    on = n > 0
    assert abs(on.mean() - 0.75) < 0.03 and n.max() == 40 and n[on].min() == 1
    assert np.all(m == (np.arange(60)[None] < n[:, None]))  # a prefix
    assert abs(n[on].mean() - 20.5) < 1.0  # uniform on 1..40
    assert np.asarray(D.observation_frames(jax.random.PRNGKey(1), 8, 60, D.DiffusionConfig())).sum() == 0

    rng = np.random.default_rng(0)
    mean = rng.normal(0, 0.1, (42, 4)).astype(np.float32)
    scale = rng.uniform(0.05, 0.2, (42, 4)).astype(np.float32)
    x = rng.normal(size=(3, 60, 42, 4)).astype(np.float32)
    obs = np.zeros((3, 60), bool)
    obs[0, :16], obs[1, :1] = True, True
    y = np.asarray(D.centre_on_observed(jnp.asarray(x), jnp.asarray(obs), jnp.asarray(mean), jnp.asarray(scale)))
    xyz = y[..., :3] * scale[:, :3] + mean[:, :3]
    mid = 0.5 * (xyz[:, :, 0] + xyz[:, :, 21])
    np.testing.assert_allclose(mid[0, :16].mean(0), 0.0, atol=1e-5)
    np.testing.assert_allclose(mid[1, 0], 0.0, atol=1e-5)
    np.testing.assert_array_equal(y[2], x[2])
    np.testing.assert_array_equal(y[..., 3], x[..., 3])  # the rotation scalar does not translate
    # a translation: every joint of a clip moves by the same amount in metres
    d = (y[0, ..., :3] - x[0, ..., :3]) * scale[:, :3]
    np.testing.assert_allclose(d, np.broadcast_to(d[:1, :1], d.shape), atol=1e-5)


def test_observation_training_feeds_the_observed_frames_clean_and_centred():
    """make_loss with diffusion.observe_prob = 1: the denoiser sees the clip re-centred on its observed frames,
    those frames clean (x_t = x0 there) and the rest noised; the default (0) gives the reference's input, the
    same draws as before the option existed."""
    from handx_jax import representation as rep
    from handx_jax.families.diffusion import make_loss

    rng = np.random.default_rng(0)
    norm = rep.NormStats(rng.normal(0, 0.1, (42, 4)), rng.uniform(0.05, 0.2, (42, 4)))
    x0 = jnp.asarray(rng.normal(size=(6, 60, 42, 4)), jnp.float32)
    seen = {}

    class Spy:  # the denoiser's interface: apply(params, x_t, t, text, mask, drop, ...) -> x̂0
        def apply(self, params, x_t, t, text, mask, drop, **kw):
            seen["x_t"], seen["t"] = x_t, t
            return jnp.zeros_like(x_t)

    batch = {"x0": x0, "text": jnp.zeros((6, 3, 2, 8)), "mask": jnp.ones((6, 3, 2), bool)}
    key = jax.random.PRNGKey(3)
    cfg = D.DiffusionConfig(observe_prob=1.0, observe_max=30)
    make_loss(Spy(), cfg, norm)(None, batch, key, True)
    obs = np.asarray(D.observation_frames(jax.random.fold_in(key, 4), 6, 60, cfg))
    x0c = np.asarray(D.centre_on_observed(x0, jnp.asarray(obs), jnp.asarray(norm.mean), jnp.asarray(norm.std)))
    x_t = np.asarray(seen["x_t"])
    assert obs.sum(1).min() >= 1
    np.testing.assert_array_equal(x_t[obs], x0c[obs])
    assert not np.any(np.all(np.isclose(x_t[~obs], x0c[~obs], atol=1e-3), axis=(-1, -2)))  # noised

    # observe_residual: the network's 0 is the last observed frame held after the observation
    res = D.DiffusionConfig(observe_prob=1.0, observe_max=30, observe_residual=True)
    total, _ = make_loss(Spy(), res, norm)(None, batch, key, True)
    held = D.held_anchor(jnp.asarray(x0c), jnp.asarray(obs))
    assert float(total) == pytest.approx(float(D.diffusion_loss(jnp.asarray(x0c), held, res)[0]), rel=1e-5)
    # ... and its input after the observation is the residual on the held frame, noised
    k_t, k_n, _, _ = jax.random.split(key, 4)
    t = jax.random.randint(k_t, (6,), 0, SCHED.T)
    want = np.asarray(D.q_sample(SCHED, jnp.asarray(x0c) - held, t, jax.random.normal(k_n, x0.shape)))
    np.testing.assert_allclose(np.asarray(seen["x_t"])[~obs], want[~obs], rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(np.asarray(seen["x_t"])[obs], x0c[obs])

    make_loss(Spy(), D.DiffusionConfig(), norm)(None, batch, key, True)
    plain = np.asarray(seen["x_t"])
    k_t, k_n, _, _ = jax.random.split(key, 4)
    want = D.q_sample(SCHED, x0, jax.random.randint(k_t, (6,), 0, SCHED.T), jax.random.normal(k_n, x0.shape))
    np.testing.assert_allclose(plain, np.asarray(want), rtol=1e-6, atol=1e-6)


def test_the_residual_output_holds_the_last_observed_frame():
    """diffusion.observe_residual: x̂0 = the last observed frame held + the network's output, after the observation;
    a network that outputs 0 predicts exactly the hold-the-last-frame baseline, whatever the noise, and the
    observation itself is kept."""
    g = np.zeros((F, J), np.float32)
    g[:2] = 1.0  # frames 0, 1 observed (all joints)
    cfg = D.DiffusionConfig(observe_prob=1.0, observe_residual=True)
    out = np.asarray(D.sample(lambda x, t_B, u: jnp.zeros_like(x), D.cosine_schedule(100), (4, F, J, C),
                              jax.random.PRNGKey(0), cfg, sampler="ddim", steps=5, guidance=2.5,
                              target=TARGET[:4], gamma_FxJ=g))
    tgt = np.asarray(TARGET[:4])
    np.testing.assert_array_equal(out[:, :2], tgt[:, :2])
    np.testing.assert_allclose(out[:, 2:], np.broadcast_to(tgt[:, 1:2], out[:, 2:].shape), atol=1e-6)
    obs = jnp.asarray(np.arange(F)[None] < np.array([[3], [0], [1], [4]]))
    a = np.asarray(D.held_anchor(TARGET[:4], obs))
    np.testing.assert_array_equal(a[0, 3:], np.broadcast_to(tgt[0, 2:3], a[0, 3:].shape))
    assert not a[0, :3].any() and not a[1].any() and not a[3].any()  # row 3: all 4 frames observed
    np.testing.assert_array_equal(a[2, 1:], np.broadcast_to(tgt[2, :1], a[2, 1:].shape))
    with pytest.raises(ValueError, match="observe_residual needs observation training"):
        D.DiffusionConfig(observe_residual=True)
