"""G-HTT (Wen et al., "Generative Hierarchical Temporal Transformer"): the pose block P and the action
block A, two Transformer VAEs (§3.1), as plain-pytree JAX functions; their losses (Eqs. 1–5), parameter
counts and analytic FLOPs.

- **P** (§3.1, App. B.3): the encoder E^P reads (μ̃, Σ̃, H̃_1..H̃_t) and gives refined frames H_1..t and the
  mid-level latent m ~ N(μ^P, Σ^P); the parallel decoder D^P, queried by the sinusoidal positions of the
  next t frames, cross-attends to m and predicts H_{t+1..2t}. Per-frame input is embedded per part (Eq. 11:
  FC2(p) d/2, FC3(v) d/4, FC4(r) d/4); every output token is mapped to a frame by MLP1 ([d, d, 153],
  LeakyReLU). D^P reads m alone (no skip connection to E^P's frame tokens, the paper's option left out) so
  that A's predicted latents, which have no frame tokens, decode the same way.
- **A** (§3.1): E^A reads (μ̃^A, Σ̃^A, m_1..m_n + φ_1..n), φ the sinusoidal phase (clips since the
  action's start), and gives α ~ N(μ^A, Σ^A); D^A, queried by φ_{n+1..n+n̄}, cross-attends to α and E^A's
  clip tokens ("for enhanced continuity") and outputs the future latents m^A, which D^P expands. HandX has no
  objects: the object feature ω is left out, and the clip's caption through the frozen text encoder (mean of
  its token states, FC1) stands for the CLIP action label of Eqs. 3–4.

Blocks are pre-LN with GELU (App. B.3). Tensor names carry their shape (B batch, S spans, T frames, D
width, M memory tokens).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.models import ghtt_motion as HM
from handx_jax.models.layers import sinusoidal_table

SPAN = 15  # frames per P span; see BlockConfig.span
TEXT_DIM = 768  # the frozen T5 encoder's width (the standard encoder's; the run records the real one)
TAU = 0.07  # Eq. 4's temperature


@dataclass(frozen=True)
class BlockConfig:
    """One VAE block's transformer: L layers each for encoder and decoder, width D, H heads, FF width."""

    layers: int = 2
    dim: int = 64
    heads: int = 4
    ff: int = 256


@dataclass(frozen=True)
class GHTTConfig:
    # The span t: the paper's is 16 frames (§3.3, 0.53 s at 30 fps). HandX clips are 60 frames, which 16 does
    # not divide; 15 (0.5 s) does, so a clip is exactly four spans (n = 4 latents for A, no padded span)
    # and the half-second granularity of P stays the paper's.
    span: int = SPAN
    pose: BlockConfig = BlockConfig()
    action: BlockConfig = BlockConfig()
    text_dim: int = TEXT_DIM
    max_spans: int = 16  # the phase table's length (App. B.3: n, n̄ ≤ 16)


# The size ladder (big_vision style): depth × width, P and A alike; "paper" is App. B.3's 9 + 9 layers at
# d 512, 8 heads, FF 2048.
def _sym(L, D, H, F) -> GHTTConfig:
    b = BlockConfig(L, D, H, F)
    return GHTTConfig(pose=b, action=b)


PRESETS: dict[str, GHTTConfig] = {
    "tiny": _sym(2, 64, 4, 256),
    "small": _sym(3, 128, 4, 512),
    "base": _sym(6, 256, 8, 1024),
    "paper": _sym(9, 512, 8, 2048),
}


# ------------------------------------------------------------------------------------------------
# Parameters: plain nested dicts


def _dense(key, din, dout):
    return {"w": jax.random.normal(key, (din, dout), jnp.float32) * (1.0 / math.sqrt(din)),
            "b": jnp.zeros((dout,), jnp.float32)}


def _ln(d):
    return {"g": jnp.ones((d,), jnp.float32), "b": jnp.zeros((d,), jnp.float32)}


def _attn(key, d):
    k = jax.random.split(key, 4)
    return {n: _dense(k[i], d, d) for i, n in enumerate(("q", "k", "v", "o"))}


def _layer(key, c: BlockConfig, cross: bool):
    k = jax.random.split(key, 4)
    p = {"ln1": _ln(c.dim), "self": _attn(k[0], c.dim), "ln2": _ln(c.dim),
         "ff1": _dense(k[1], c.dim, c.ff), "ff2": _dense(k[2], c.ff, c.dim)}
    if cross:
        p |= {"lnx": _ln(c.dim), "cross": _attn(k[3], c.dim)}
    return p


def _stack(key, c: BlockConfig, cross: bool):
    return {"layers": [_layer(k, c, cross) for k in jax.random.split(key, c.layers)], "ln_f": _ln(c.dim)}


def init_pose(key, cfg: GHTTConfig):
    c, d = cfg.pose, cfg.pose.dim
    k = jax.random.split(key, 8)
    return {"fc_p": _dense(k[0], 2 * HM.P_DIM, d // 2), "fc_v": _dense(k[1], 2 * HM.RIGID, d // 4),
            "fc_r": _dense(k[2], HM.RIGID, d - d // 2 - d // 4),  # Eq. 11's d/2, d/4, d/4
            "tok": jax.random.normal(k[3], (2, d), jnp.float32) * 0.02,  # μ̃^P, Σ̃^P
            "enc": _stack(k[4], c, False), "dec": _stack(k[5], c, True),
            "mlp1": [_dense(k[6], d, d), _dense(jax.random.fold_in(k[6], 1), d, d),
                     _dense(k[7], d, HM.FRAME_DIM)]}


def init_action(key, cfg: GHTTConfig):
    c, d, dp = cfg.action, cfg.action.dim, cfg.pose.dim
    k = jax.random.split(key, 6)
    return {"m_in": _dense(k[0], dp, d), "m_out": _dense(k[1], d, dp), "text": _dense(k[2], cfg.text_dim, d),  # FC1
            "tok": jax.random.normal(k[3], (2, d), jnp.float32) * 0.02,  # μ̃^A, Σ̃^A
            "enc": _stack(k[4], c, False), "dec": _stack(k[5], c, True)}


def count(params) -> int:
    return int(sum(np.prod(x.shape) for x in jax.tree_util.tree_leaves(params)))


def param_counts(cfg: GHTTConfig) -> dict:
    """Parameters of P and A from shapes alone (jax.eval_shape: nothing allocated)."""
    p = jax.eval_shape(lambda k: init_pose(k, cfg), jax.random.PRNGKey(0))
    a = jax.eval_shape(lambda k: init_action(k, cfg), jax.random.PRNGKey(0))
    n_p, n_a = count(p), count(a)
    # the learned tokens and FC1 (text → d) are the "embedding" side, as position tables are elsewhere
    emb = 2 * cfg.pose.dim + 2 * cfg.action.dim + (cfg.text_dim + 1) * cfg.action.dim
    return {"params": n_p + n_a, "params_pose": n_p, "params_action": n_a, "params_non_embedding": n_p + n_a - emb}


# ------------------------------------------------------------------------------------------------
# Blocks (pre-LN, GELU: App. B.3)


def _lin(p, x):
    return x @ p["w"] + p["b"]


def _layer_norm(p, x, eps=1e-5):
    mu = x.mean(-1, keepdims=True)
    var = ((x - mu) ** 2).mean(-1, keepdims=True)
    return (x - mu) * jax.lax.rsqrt(var + eps) * p["g"] + p["b"]


def _attend(p, x_BxQxD, mem_BxMxD, mask_BxQxM, heads):
    B, Q, D = x_BxQxD.shape
    split = lambda t: t.reshape(B, t.shape[1], heads, D // heads)  # noqa: E731
    q, k, v = split(_lin(p["q"], x_BxQxD)), split(_lin(p["k"], mem_BxMxD)), split(_lin(p["v"], mem_BxMxD))
    att_BxHxQxM = jnp.einsum("bqhd,bmhd->bhqm", q, k) / math.sqrt(D // heads)
    att_BxHxQxM = jnp.where(mask_BxQxM[:, None], att_BxHxQxM, -1e9)
    out = jnp.einsum("bhqm,bmhd->bqhd", jax.nn.softmax(att_BxHxQxM, -1), v).reshape(B, Q, D)
    return _lin(p["o"], out)


def transformer(p, x_BxTxD, mask_BxT, heads, mem_BxMxD=None, mem_mask_BxM=None):
    """Pre-LN encoder (mem None) or parallel decoder stack; padded tokens (mask False) are never attended to."""
    self_mask = mask_BxT[:, None, :] & jnp.ones_like(mask_BxT)[:, :, None]
    for lp in p["layers"]:
        x_BxTxD = x_BxTxD + _attend(lp["self"], _layer_norm(lp["ln1"], x_BxTxD), _layer_norm(lp["ln1"], x_BxTxD),
                                    self_mask, heads)
        if mem_BxMxD is not None:
            xmask = jnp.broadcast_to(mem_mask_BxM[:, None, :], (x_BxTxD.shape[0], x_BxTxD.shape[1], mem_BxMxD.shape[1]))
            x_BxTxD = x_BxTxD + _attend(lp["cross"], _layer_norm(lp["lnx"], x_BxTxD), mem_BxMxD, xmask, heads)
        h = jax.nn.gelu(_lin(lp["ff1"], _layer_norm(lp["ln2"], x_BxTxD)))
        x_BxTxD = x_BxTxD + _lin(lp["ff2"], h)
    return _layer_norm(p["ln_f"], x_BxTxD)


def _mlp1(p, x):
    x = jax.nn.leaky_relu(_lin(p[0], x))
    x = jax.nn.leaky_relu(_lin(p[1], x))
    return _lin(p[2], x)


# ------------------------------------------------------------------------------------------------
# P block


def pose_encode(p, cfg: GHTTConfig, H_BxTx153):
    """E^P: (μ^P, log Σ^P) (B, D) and the refined frames (B, T, 153), all in normalised units."""
    B, T, _ = H_BxTx153.shape
    x = jnp.concatenate([_lin(p["fc_p"], H_BxTx153[..., HM.P_SLICE]), _lin(p["fc_v"], H_BxTx153[..., HM.V_SLICE]),
                         _lin(p["fc_r"], H_BxTx153[..., HM.R_SLICE])], -1)  # Eq. 11
    x = jnp.concatenate([jnp.broadcast_to(p["tok"], (B, 2, cfg.pose.dim)), x], 1)
    x = x + jnp.asarray(sinusoidal_table(T + 2, cfg.pose.dim))
    y = transformer(p["enc"], x, jnp.ones((B, T + 2), bool), cfg.pose.heads)
    return y[:, 0], y[:, 1], _mlp1(p["mlp1"], y[:, 2:])


def pose_decode(p, cfg: GHTTConfig, m_BxD):
    """D^P: the next span's frames (B, t, 153) from the latent m, queried by the positions t+1..2t."""
    B, t, D = m_BxD.shape[0], cfg.span, cfg.pose.dim
    q = jnp.broadcast_to(jnp.asarray(sinusoidal_table(2 * t + 2, D)[t + 2:]), (B, t, D))
    y = transformer(p["dec"], q, jnp.ones((B, t), bool), cfg.pose.heads, m_BxD[:, None], jnp.ones((B, 1), bool))
    return _mlp1(p["mlp1"], y)


def reparameterize(key, mu, logvar, scale: float = 1.0):
    """m ~ N(μ, scale·Σ) (§4.2 samples with scale 5 for prediction)."""
    return mu + jnp.sqrt(scale) * jnp.exp(0.5 * logvar) * jax.random.normal(key, mu.shape, mu.dtype)


def kl_normal(mu, logvar):
    """KL(N(μ, diag e^logvar) ‖ N(0, I)) per row, summed over dimensions."""
    return 0.5 * jnp.sum(jnp.exp(logvar) + mu ** 2 - 1.0 - logvar, -1)


# ------------------------------------------------------------------------------------------------
# A block


def phase(cfg: GHTTConfig, D):
    return jnp.asarray(sinusoidal_table(cfg.max_spans + 1, D))


def action_encode(p, cfg: GHTTConfig, m_BxSxDp, obs_BxS):
    """E^A over the observed spans' latents (``obs`` marks them; phase j = span index from the action's
    start): (μ^A, log Σ^A) (B, D) and its clip tokens (B, S, D)."""
    B, S, _ = m_BxSxDp.shape
    D = cfg.action.dim
    x = _lin(p["m_in"], m_BxSxDp) + phase(cfg, D)[1:S + 1]
    x = jnp.concatenate([jnp.broadcast_to(p["tok"], (B, 2, D)), x], 1)
    mask = jnp.concatenate([jnp.ones((B, 2), bool), obs_BxS], 1)
    y = transformer(p["enc"], x, mask, cfg.action.heads)
    return y[:, 0], y[:, 1], y[:, 2:]


def action_decode(p, cfg: GHTTConfig, alpha_BxD, clips_BxSxD, obs_BxS, query_BxS):
    """D^A: the latents m^A (B, S, D_P) of the queried spans (phase embeddings as queries; the rest masked),
    cross-attending to α and the observed clip tokens."""
    B, S, D = clips_BxSxD.shape
    q = jnp.broadcast_to(phase(cfg, D)[1:S + 1], (B, S, D))
    mem = jnp.concatenate([alpha_BxD[:, None], clips_BxSxD], 1)
    mem_mask = jnp.concatenate([jnp.ones((B, 1), bool), obs_BxS], 1)
    y = transformer(p["dec"], q, query_BxS | ~query_BxS.any(1, keepdims=True), cfg.action.heads, mem, mem_mask)
    return _lin(p["m_out"], y)


def text_embed(p, pooled_BxDt):
    """a = FC1(text feature) (§3.1, Eq. 3's label embedding)."""
    return _lin(p["text"], pooled_BxDt)


def action_loss(alpha_BxD, a_BxD, tau: float = TAU):
    """Eqs. 3–4 with the batch's captions as the label set (each clip's own caption the GT): per clip,
    ‖α − a_gt‖₁ (mean over dims) − log Pr(a_gt | α), Pr the softmax of cosine similarities / τ. Returns the
    two terms' batch means (l1, nce)."""
    an = alpha_BxD / jnp.linalg.norm(alpha_BxD, axis=-1, keepdims=True).clip(1e-6)
    tn = a_BxD / jnp.linalg.norm(a_BxD, axis=-1, keepdims=True).clip(1e-6)
    logits_BxB = an @ tn.T / tau
    nce = -jnp.mean(jnp.diagonal(jax.nn.log_softmax(logits_BxB, -1)))
    return jnp.mean(jnp.abs(alpha_BxD - a_BxD)), nce


# ------------------------------------------------------------------------------------------------
# Analytic forward FLOPs (2 per multiply-add; softmax, norms and activations left out)


def _stack_flops(c: BlockConfig, T: int, M: int = 0) -> int:
    D, F = c.dim, c.ff
    per = 2 * 4 * T * D * D + 2 * 2 * T * T * D + 2 * 2 * T * D * F  # self-attention + FF
    if M:
        per += 2 * (2 * T * D * D + 2 * M * D * D) + 2 * 2 * T * M * D  # cross: q, o over T; k, v over M
    return c.layers * per


def forward_flops(cfg: GHTTConfig, frames: int = 60) -> dict:
    """Forward FLOPs of one 60-frame clip through the whole model as it is used: E^P and D^P over each of its
    spans (P's training sample is two spans: one encoded, the next decoded), E^A over the spans' latents and
    D^A over as many queries, FC1 on the caption feature. Returns pose, action and total."""
    t, S = cfg.span, frames // cfg.span
    P, A = cfg.pose, cfg.action
    emb = 2 * t * (2 * HM.P_DIM * (P.dim // 2) + 2 * HM.RIGID * (P.dim // 4) + HM.RIGID * (P.dim - P.dim // 2 - P.dim // 4))
    mlp1 = 2 * 2 * t * (2 * P.dim * P.dim + P.dim * HM.FRAME_DIM)  # refined + predicted frames
    pose = S * (_stack_flops(P, t + 2) + _stack_flops(P, t, 1) + emb // 2 + mlp1)
    action = (_stack_flops(A, S + 2) + _stack_flops(A, S, S + 1) + 2 * 2 * S * P.dim * A.dim
              + 2 * cfg.text_dim * A.dim)
    return {"pose": int(pose), "action": int(action), "total": int(pose + action)}


def replace_sizes(cfg: GHTTConfig, layers=None, dim=None, heads=None, ff=None) -> GHTTConfig:
    """Both blocks at another depth/width (the sweep's axes)."""
    def one(b):
        return BlockConfig(layers or b.layers, dim or b.dim, heads or b.heads, ff or (4 * dim if dim else b.ff))
    return dataclasses.replace(cfg, pose=one(cfg.pose), action=one(cfg.action))
