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
