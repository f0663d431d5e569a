"""Gaussian diffusion for x0-predicting denoisers: schedule, losses, samplers, masked partial denoising.

Reference §3.4–§3.8 and paper App. D. Every sampler is a single jitted ``lax.scan`` over timesteps;
classifier-free guidance evaluates the conditional and the unconditional pass in one batched call,
and the unconditional pass uses the null text embedding on all three branches (the reference's
guidance is a no-op, §9.6, and is not ported).

Arrays are in normalised diffusion space ``(B, F, 42, 4)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np


BLENDS = ("x0", "x0_renoise", "xt")


@dataclass(frozen=True)
class DiffusionConfig:
    steps: int = 1000
    cond_drop: float = 0.1  # per-branch, independent (reference §3.2)
    # All three branches dropped at once (the null input classifier-free guidance extrapolates from).
    # The reference only drops branches independently, so all-three-null appears in cond_drop³ = 0.1%
    # of samples; MDM drops the whole condition with p = 0.1 (issue 14.3). See cond_drop_mask.
    joint_drop: float = 0.1
    guidance: float = 2.5
    # Loss weights (reference §3.5): xyz, all channels, velocity, predicted acceleration → 0.
    w_pos: float = 1.0
    w_repr: float = 0.5
    w_vel: float = 0.2
    w_acc: float = 0.1
    # Masked partial denoising (paper App. D): γ = p_hard at constrained frames, decaying linearly
    # to p_soft over k_trans frames. The blend (see ``sample``):
    #   "x0"         blend the clean prediction with the target (Eq. K), then the sampler's ordinary
    #                step from (x_t, blended x̂0): the DDPM posterior or the DDIM update;
    #   "x0_renoise" Eq. K, then Eq. L read literally: x_{t−1} = √ᾱ_{t−1}·x̂0 + √(1−ᾱ_{t−1})·ε with a
    #                fresh ε. It discards x_t, so free joints lose variance (0.12 vs 0.25 on the
    #                Gaussian toy of tests/test_diffusion_sampler.py); kept for comparison;
    #   "xt"         blend x_{t−1} with the target re-noised to t−1 using the same ε (the code, §3.8).
    p_hard: float = 0.85
    p_soft: float = 0.10
    k_trans: int = 5
    blend: str = "x0"
    # Observation-conditioned training (issue 41 item 3, motion prediction): with this probability a
    # training item's first n frames (n uniform in 1..observe_max) enter the denoiser clean, as the
    # sampler's prediction task gives them, and the item is centred on those frames' mean wrist midpoint
    # (as prediction centres its observation, not on the hidden whole clip). A run trained so reads its
    # hard-constrained frames (γ = 1) clean at every sampling step (``sample``). 0 = off: the reference's
    # training, and every published text-to-motion number.
    observe_prob: float = 0.0
    observe_max: int = 40
    # With observation training: the frames after the observation are diffused as residuals on the last
    # observed frame held (normalised features; the observed frames stay as they are, clean), so the
    # denoiser's input and output there are the motion away from holding still and x̂0 = held + output: a
    # network that outputs 0 is the hold-the-last-frame predictor (a residual connection, as motion
    # prediction models since Martinez et al. 2017 use). Adding the held frame to the output only, with
    # the input left absolute, fought the denoiser's near-identity at small t: 88 mm at frame 17 after
    # 200 steps (docs/results/prediction/prefix4000).
    observe_residual: bool = False

    def __post_init__(self):
        if self.blend not in BLENDS:
            raise ValueError(f"diffusion.blend must be one of {', '.join(BLENDS)}; got {self.blend!r}")
        for name in ("cond_drop", "joint_drop"):
            v = getattr(self, name)
            if not 0 <= v < 1:
                raise ValueError(f"diffusion.{name} must be in [0, 1), got {v}")
        if not 0 <= self.observe_prob <= 1:
            raise ValueError(f"diffusion.observe_prob must be in [0, 1], got {self.observe_prob}")
        if self.observe_max < 1:
            raise ValueError(f"diffusion.observe_max must be at least 1, got {self.observe_max}")
        if self.observe_residual and not self.observe_prob:
            raise ValueError("diffusion.observe_residual needs observation training (diffusion.observe_prob > 0)")


@dataclass(frozen=True)
class Schedule:
    betas: np.ndarray
    alphas_cumprod: np.ndarray
    alphas_cumprod_prev: np.ndarray
    posterior_var: np.ndarray
    posterior_logvar_clipped: np.ndarray
    coef_x0: np.ndarray
    coef_xt: np.ndarray

    @property
    def T(self) -> int:
        return len(self.betas)


def cosine_schedule(T: int = 1000, s: float = 0.008) -> Schedule:
    """ᾱ(u) = cos²(((u + s)/(1 + s))·π/2); β_i = min(1 − ᾱ((i+1)/T)/ᾱ(i/T), 0.999) (reference §3.4)."""
    f = lambda u: np.cos((u + s) / (1 + s) * np.pi / 2) ** 2  # noqa: E731
    i = np.arange(T, dtype=np.float64)
    betas = np.minimum(1 - f((i + 1) / T) / f(i / T), 0.999)
    ac = np.cumprod(1 - betas)
    ac_prev = np.append(1.0, ac[:-1])
    post_var = betas * (1 - ac_prev) / (1 - ac)
    # FIXED_SMALL with the log clipped by reusing index 1 at index 0 (reference §3.4).
    post_logvar = np.log(np.append(post_var[1], post_var[1:]))
    return Schedule(
        betas=betas, alphas_cumprod=ac, alphas_cumprod_prev=ac_prev, posterior_var=post_var,
        posterior_logvar_clipped=post_logvar,
        coef_x0=betas * np.sqrt(ac_prev) / (1 - ac),
        coef_xt=(1 - ac_prev) * np.sqrt(1 - betas) / (1 - ac),
    )


def _b(v, t_B, ndim):
    """Gather schedule values at t and broadcast to (B, 1, 1, 1)."""
    return jnp.asarray(v, jnp.float32)[t_B].reshape((-1,) + (1,) * (ndim - 1))


def q_sample(sched: Schedule, x0, t_B, noise):
    ac = _b(sched.alphas_cumprod, t_B, x0.ndim)
    return jnp.sqrt(ac) * x0 + jnp.sqrt(1 - ac) * noise


def diffusion_loss(x0, x0_hat, cfg: DiffusionConfig):
    """x0-objective terms of reference §3.5 (means over frames, joints and the slice's channels)."""
    p, ph = x0[..., :3], x0_hat[..., :3]
    l_pos = jnp.mean((p - ph) ** 2)
    l_repr = jnp.mean((x0 - x0_hat) ** 2)
    l_vel = jnp.mean((jnp.diff(p, axis=1) - jnp.diff(ph, axis=1)) ** 2)
    l_acc = jnp.mean(jnp.diff(ph, n=2, axis=1) ** 2)
    total = cfg.w_pos * l_pos + cfg.w_repr * l_repr + cfg.w_vel * l_vel + cfg.w_acc * l_acc
    return total, {"l_pos": l_pos, "l_repr": l_repr, "l_vel": l_vel, "l_acc": l_acc}


def cond_drop_mask(rng: jax.Array, B: int, cfg: DiffusionConfig) -> jax.Array:
    """Training-time text dropout (B, 3) bool, True = the branch sees the null embedding.

    A joint drop nulls all three branches with p = ``joint_drop``; otherwise each branch is dropped
    independently with p = ``cond_drop`` (reference §3.2). Classifier-free guidance extrapolates from
    the all-three-null input, which the per-branch drops alone give with p = cond_drop³ (0.1%); with
    the joint drop it has p = joint_drop + (1 − joint_drop)·cond_drop³ (10.09% at the defaults).
    """
    k_joint, k_branch = jax.random.split(rng)
    joint_Bx1 = jax.random.bernoulli(k_joint, cfg.joint_drop, (B, 1))
    return joint_Bx1 | jax.random.bernoulli(k_branch, cfg.cond_drop, (B, 3))


def observation_frames(rng: jax.Array, B: int, F: int, cfg: DiffusionConfig) -> jax.Array:
    """Training-time observation mask (B, F) bool, True = the frame enters the denoiser clean: for a
    fraction ``observe_prob`` of the items the first n frames, n uniform in 1..min(observe_max, F − 1)
    (at least one frame is always left to predict); none for the others."""
    k_on, k_n = jax.random.split(rng)
    on_B = jax.random.bernoulli(k_on, cfg.observe_prob, (B,))
    n_B = jax.random.randint(k_n, (B,), 1, min(cfg.observe_max, F - 1) + 1)
    return on_B[:, None] & (jnp.arange(F)[None, :] < n_B[:, None])


def held_anchor(x_BxFxJxC, obs_BxF):
    """Each row's last observed frame held over the frames after its observation, 0 on the observed frames
    and on rows with none: what ``observe_residual`` adds to the network's output."""
    F = x_BxFxJxC.shape[1]
    n_B = obs_BxF.sum(1)
    last_BxJxC = jnp.take_along_axis(x_BxFxJxC, jnp.maximum(n_B - 1, 0)[:, None, None, None], axis=1)[:, 0]
    after_BxF = (jnp.arange(F)[None, :] >= n_B[:, None]) & (n_B > 0)[:, None]
    return jnp.where(after_BxF[:, :, None, None], last_BxJxC[:, None], 0.0)


def centre_on_observed(x0_BxFx42x4, obs_BxF, mean_42x4, scale_42x4):
    """Re-centre normalised clips on their observed frames' mean wrist midpoint (rows with no observed
    frame unchanged): the prediction task places its observation so (``sampling.generate``), because the
    whole clip's centre would tell the model where the hidden future goes. ``scale`` is the
    normalisation's std + eps; a translation only moves the xyz channels."""
    xyz = x0_BxFx42x4[..., :3] * scale_42x4[:, :3] + mean_42x4[:, :3]
    mid_BxFx3 = 0.5 * (xyz[:, :, 0] + xyz[:, :, 21])
    w_BxF = obs_BxF.astype(x0_BxFx42x4.dtype)
    c_Bx3 = (w_BxF[..., None] * mid_BxFx3).sum(1) / jnp.maximum(w_BxF.sum(1), 1.0)[:, None]
    return x0_BxFx42x4.at[..., :3].add(-c_Bx3[:, None, None, :] / scale_42x4[:, :3])


# ------------------------------------------------------------------------------------------------
# Masks for versatile generation (paper App. D.2)


def soft_mask(centers_FxJ: np.ndarray, p_hard: float = 0.85, p_soft: float = 0.10, k_trans: int = 5) -> np.ndarray:
    """γ (F, J) from boolean centre frames per joint (Eq. H–J): p_hard at centres, linear decay to
    p_soft at distance k_trans, maximum over overlapping windows, 0 elsewhere."""
    c = np.asarray(centers_FxJ, bool)
    F = c.shape[0]
    g = np.zeros(c.shape, np.float32)
    frames = np.arange(F)
    for j in range(c.shape[1]):
        idx = np.flatnonzero(c[:, j])
        if not len(idx):
            continue
        d = np.abs(frames[:, None] - idx[None, :]).min(1)
        w = p_hard - (p_hard - p_soft) * d / max(k_trans, 1)
        g[:, j] = np.where(d <= k_trans, w, 0.0)
    return g


TASKS = ("text2motion", "inbetween", "keyframes", "wrist", "reaction", "long", "prediction")


def task_centers(task: str, frames: int = 60, joints: int = 42, *, k_inbet: int = 5, keyframes=(30,),
                 fixed_hand: str = "left", k_hor: int = 5, observed: int = 20) -> np.ndarray:
    """Boolean centre frames (F, J) for each task of App. D.2, and for ``prediction`` (G-HTT's motion
    prediction, issue 33): the first ``observed`` frames."""
    c = np.zeros((frames, joints), bool)
    if task == "text2motion":
        pass
    elif task == "inbetween":
        c[:k_inbet] = True
        c[frames - k_inbet:] = True
    elif task == "keyframes":
        c[list(keyframes)] = True
    elif task == "wrist":
        c[:, [0, 21]] = True
    elif task == "reaction":
        c[:, slice(0, 21) if fixed_hand == "left" else slice(21, 42)] = True
    elif task == "long":
        c[:k_hor] = True
    elif task == "prediction":
        c[:observed] = True
    else:
        raise ValueError(f"unknown task {task!r}; choose from {TASKS}")
    return c


# ------------------------------------------------------------------------------------------------
# Samplers


DenoiseFn = Callable[[jax.Array, jax.Array, jax.Array], jax.Array]  # (x_t, t_B, uncond_B) → x̂0


def guided(denoise: DenoiseFn, scale: float) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """CFG: x̂0 = u + s·(c − u), with c and u from one batched call (u = null text on all branches).

    The batch is [x; x]: the unconditional half repeats the conditional half's x and t exactly, which
    a denoiser may use to share the work that does not see the text (``TrebleDenoiser.denoise``)."""
    def fn(x, t_B):
        if scale == 1.0:
            return denoise(x, t_B, jnp.zeros(x.shape[0], bool))
        B = x.shape[0]
        both = denoise(jnp.concatenate([x, x]), jnp.concatenate([t_B, t_B]),
                       jnp.concatenate([jnp.zeros(B, bool), jnp.ones(B, bool)]))
        c, u = both[:B], both[B:]
        return u + scale * (c - u)
    return fn


def respaced_timesteps(T: int, steps: int) -> np.ndarray:
    """Evenly spaced timesteps from T−1 down to 0 (``steps`` of them)."""
    return np.unique(np.round(np.linspace(0, T - 1, steps)).astype(np.int64))[::-1].copy()


def sample(denoise: DenoiseFn, sched: Schedule, shape, rng, cfg: DiffusionConfig, *, sampler: str = "ddpm",
           steps: int | None = None, guidance: float | None = None, target=None, gamma_FxJ=None, steer=None):
    """Draw samples with a single ``lax.scan`` over timesteps.

    ``sampler``: "ddpm" (ancestral over all T steps, FIXED_SMALL variance, reference §3.4) or "ddim"
    (deterministic DDIM on ``steps`` respaced timesteps). ``target`` (B, F, J, C) and ``gamma_FxJ``
    enable masked partial denoising (``cfg.blend``, see :class:`DiffusionConfig`); γ = 0 everywhere
    gives exactly the unmasked sampler's output with the default blend "x0".

    With blend "x0", each step blends x̂0 with the target (paper Eq. K) and then takes the sampler's
    ordinary step from (x_t, blended x̂0). Where γ = 0 that is the unmasked step, so free joints keep
    the exact sampler's statistics; Eq. L read literally ("x0_renoise") re-noises the blended x̂0 with
    fresh noise and forgets x_t, which shrinks their variance.

    ``steer(x0_hat, t) -> x0_hat``: applied to the clean prediction (after CFG, before the mask blend, so
    constrained joints still end on their target) at every step, e.g. contact guidance (handx_jax/families/diffusion/guidance.py,
    BimArt Eq. 6). None traces nothing extra: the compiled sampler is the unguided one.
    """
    s = cfg.guidance if guidance is None else guidance
    model = guided(denoise, s)
    ac = jnp.asarray(sched.alphas_cumprod, jnp.float32)
    T = sched.T
    if sampler == "ddpm":
        ts = np.arange(T - 1, -1, -1)
    elif sampler == "ddim":
        ts = respaced_timesteps(T, steps or 50)
    else:
        raise ValueError(f"unknown sampler {sampler!r}")
    if cfg.blend not in BLENDS:
        raise ValueError(f"unknown blend {cfg.blend!r}; choose from {BLENDS}")
    ts_prev = np.append(ts[1:], -1)
    masked = target is not None and gamma_FxJ is not None
    g = jnp.asarray(gamma_FxJ, jnp.float32)[None, :, :, None] if masked else None
    # A run trained with observed frames clean (``observe_prob``) is given its hard-constrained entries
    # (γ = 1: the prediction task's observation) clean in x_t at every step, as in training; noised
    # copies of them (the blends below) are inputs it was not trained on. Soft masks (γ < 1) are untouched.
    clean = g >= 1.0 if masked and cfg.observe_prob > 0 else None
    anchor = None
    if masked and cfg.observe_residual:  # the observation is the frames all of whose joints are hard (a prefix)
        # The whole chain runs on x − anchor (0 on the observed frames, so their target is unchanged) and
        # the anchor comes back at the end: the residual space the run was trained in.
        obs_BxF = jnp.broadcast_to(jnp.all(g[0, :, :, 0] >= 1.0, axis=1)[None], shape[:2])
        anchor = held_anchor(jnp.asarray(target, jnp.float32), obs_BxF)
    rng_init, rng_loop = jax.random.split(rng)
    x_T = jax.random.normal(rng_init, shape)
    B = shape[0]

    def body(x, inp):
        t, t_prev, key = inp
        t_B = jnp.full((B,), t, jnp.int32)
        if clean is not None:
            x = jnp.where(clean, target, x)
        x0_hat = model(x, t_B)
        if steer is not None:
            x0_hat = steer(x0_hat, t)
        eps = jax.random.normal(key, x.shape)
        ac_prev = jnp.where(t_prev >= 0, ac[jnp.maximum(t_prev, 0)], 1.0)
        if masked and cfg.blend in ("x0", "x0_renoise"):
            x0_hat = (1 - g) * x0_hat + g * target  # paper Eq. K
            if cfg.blend == "x0_renoise":
                # Paper Eq. L read literally: re-noise the blended x̂0 to t−1 with fresh noise (x_t unused).
                return jnp.sqrt(ac_prev) * x0_hat + jnp.where(t_prev >= 0, jnp.sqrt(1 - ac_prev), 0.0) * eps, None
        if sampler == "ddpm":
            # Posterior q(x_{t−1} | x_t, x̂0) (reference §3.4); at t = 0, coef_x0 = 1 and coef_xt = 0.
            mean = (jnp.asarray(sched.coef_x0, jnp.float32)[t] * x0_hat
                    + jnp.asarray(sched.coef_xt, jnp.float32)[t] * x)
            sigma = jnp.exp(0.5 * jnp.asarray(sched.posterior_logvar_clipped, jnp.float32)[t])
            x_prev = mean + jnp.where(t > 0, sigma, 0.0) * eps
        else:
            a_t = ac[t]
            eps_hat = (x - jnp.sqrt(a_t) * x0_hat) / jnp.sqrt(1 - a_t)
            x_prev = jnp.sqrt(ac_prev) * x0_hat + jnp.sqrt(1 - ac_prev) * eps_hat
        if masked and cfg.blend == "xt":
            # Reference §3.8: blend x_{t−1} with the target re-noised to t−1 using the same ε; at the
            # last step blend with the clean target.
            tgt = jnp.where(t_prev >= 0, jnp.sqrt(ac_prev) * target + jnp.sqrt(1 - ac_prev) * eps, target)
            x_prev = g * tgt + (1 - g) * x_prev
        return x_prev, None

    keys = jax.random.split(rng_loop, len(ts))
    x0, _ = jax.lax.scan(body, x_T, (jnp.asarray(ts, jnp.int32), jnp.asarray(ts_prev, jnp.int32), keys))
    return x0 if anchor is None else x0 + anchor
