"""BimArt's two denoisers (§3.2-3.3) as plain-pytree JAX functions, their parameter counts and analytic FLOPs.

Both are the same shape (§3.5: "The contact and motion models share the same architecture hyperparameters"): a
transformer encoder over the clip's N frames that reads the noisy sample x_t and predicts the clean x0, one token
per frame = in(x_t frame) + Z frame + the timestep's embedding + the frame's sinusoidal position.

- **Contact model** (§3.2, Eq. 4): x = per frame both hands' contact maps over both parts' K mapped points
  (4K values); Z = E_o(O, G, s_o), an MLP of the per-frame object features (objects/features.py).
- **Motion model** (§3.3): x = per frame X = [H | D] of both hands (or the joints, ``hand_rep``); Z = [Z_o | Z_c],
  Z_o = E_alpha(O, G, s_o) and Z_c = E_c(C) (MLPs, each half the width, concatenated), Z_c replaced by a learned
  null token in training with probability p_f and for the unconditional half of classifier-free guidance.

The transformer blocks are G-HTT's (models/ghtt.py: pre-LN, GELU), a model of this project already written as
pure functions of plain pytrees; ``BlockConfig`` gives depth, width, heads and FF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.models.ghtt import BlockConfig, _dense, _lin, _stack, _stack_flops, count, transformer
from handx_jax.models.layers import sinusoidal_table
from handx_jax.objects.features import feature_dim

FRAMES = 60
HAND_REPS = ("surface", "joints")  # X = [H | D] (the paper's), or the 21 joints (Tab. 3's MANO-Rep stand-in)


@dataclass(frozen=True)
class BimArtConfig:
    """One denoiser: its transformer, K basis points per part (the corpus's ``bps_k``), J hand-surface keypoints
    per hand (the paper's 100 MANO vertices), the hand representation, the diffusion steps (§3.5: 50)."""

    block: BlockConfig = BlockConfig(2, 64, 4, 256)
    k: int = 64
    keypoints: int = 32
    hand_rep: str = "surface"
    steps: int = 50
    frames: int = FRAMES
    # Tab. 3's "no object conditioning" control: the motion model's Z_o is zero (the contact model keeps E_o), so
    # the hands see the object only through the contact embedding, and nothing at all in the null-token half.
    object_condition: bool = True


PRESETS: dict[str, BimArtConfig] = {
    "tiny": BimArtConfig(BlockConfig(2, 64, 4, 256), k=64, keypoints=32),
    "small": BimArtConfig(BlockConfig(4, 128, 4, 512), k=64, keypoints=64),
    # §3.5: eight encoder layers, latent 512; K = 512 basis points, J = 100 hand vertices, 50 diffusion steps.
    "paper": BimArtConfig(BlockConfig(8, 512, 8, 2048), k=512, keypoints=100),
}

JOINTS = 21


def hand_points(cfg: BimArtConfig) -> int:
    """Keypoints per hand in X: the 21 joints, then (surface rep) J points on the hand surface."""
    return JOINTS + (cfg.keypoints if cfg.hand_rep == "surface" else 0)


def motion_dim(cfg: BimArtConfig) -> int:
    """Values per frame of X: per hand and keypoint its position H (3) and, surface rep, D (3)."""
    return 2 * hand_points(cfg) * (6 if cfg.hand_rep == "surface" else 3)


def contact_dim(cfg: BimArtConfig) -> int:
    return 2 * 2 * cfg.k  # hands x parts x basis points


def _mlp(key, din, dh, dout):
    k1, k2 = jax.random.split(key)
    return [_dense(k1, din, dh), _dense(k2, dh, dout)]


def _run_mlp(p, x):
    return _lin(p[1], jax.nn.gelu(_lin(p[0], x)))


def init(key, cfg: BimArtConfig, kind: str):
    """Parameters of the contact (``kind="contact"``) or motion (``"motion"``) denoiser."""
    d = cfg.block.dim
    k = jax.random.split(key, 6)
    x_dim = contact_dim(cfg) if kind == "contact" else motion_dim(cfg)
    p = {"x_in": _dense(k[0], x_dim, d), "x_out": _dense(k[1], d, x_dim), "t_mlp": _mlp(k[2], d, d, d),
         "enc": _stack(k[3], cfg.block, False)}
    if kind == "contact":
        p["obj"] = _mlp(k[4], feature_dim(cfg.k), d, d)                       # E_o
    else:
        p["obj"] = _mlp(k[4], feature_dim(cfg.k), d, d // 2)                  # E_alpha -> Z_o
        p["con"] = _mlp(k[5], contact_dim(cfg), d, d - d // 2)                # E_c -> Z_c
        p["null"] = jnp.zeros((d - d // 2,), jnp.float32)                     # the learned null token
    return p


def _time_embedding(p, t_B, d):
    half = d // 2
    freqs = np.exp(-math.log(10000.0) * np.arange(half) / half).astype(np.float32)
    a = t_B.astype(jnp.float32)[:, None] * freqs[None]
    return _run_mlp(p["t_mlp"], jnp.concatenate([jnp.sin(a), jnp.cos(a)], -1))


def denoise(p, cfg: BimArtConfig, x_t_BxFxX, t_B, obj_BxFxO, contact_BxFxC=None, null_B=None):
    """x̂0 (B, F, X). Motion model: ``contact`` the contact maps (normalised), ``null_B`` True where Z_c is the
    null token (classifier-free guidance's unconditional pass, or the training drop)."""
    B, F, _ = x_t_BxFxX.shape
    d = cfg.block.dim
    z = _run_mlp(p["obj"], obj_BxFxO)
    if "con" in p and not cfg.object_condition:
        z = jnp.zeros_like(z)
    if "con" in p:
        zc = _run_mlp(p["con"], contact_BxFxC)
        zc = jnp.where(null_B[:, None, None], p["null"], zc)
        z = jnp.concatenate([z, zc], -1)                                      # Z = [Z_o | Z_c]
    h = _lin(p["x_in"], x_t_BxFxX) + z + _time_embedding(p, t_B, d)[:, None] + sinusoidal_table(F, d)[None]
    h = transformer(p["enc"], h, jnp.ones((B, F), bool), cfg.block.heads)
    return _lin(p["x_out"], h)


# ------------------------------------------------------------------------------------------------
# Sizes: parameters from shapes (nothing allocated) and analytic forward FLOPs of one clip


def param_count(cfg: BimArtConfig, kind: str) -> dict:
    p = jax.eval_shape(lambda key: init(key, cfg, kind), jax.random.PRNGKey(0))
    n = count(p)
    d = cfg.block.dim
    # the input/output projections, the condition encoders and the time MLP are the "embedding" side
    emb = n - count(p["enc"])
    return {"params": n, "params_non_embedding": n - emb if n > emb else n, "width": d}


def forward_flops(cfg: BimArtConfig, kind: str, frames: int | None = None) -> int:
    """FLOPs (2 per multiply-add; norms, softmax and activations left out) of one denoiser pass over a clip."""
    F = frames or cfg.frames
    d = cfg.block.dim
    x = contact_dim(cfg) if kind == "contact" else motion_dim(cfg)
    o = feature_dim(cfg.k)
    f = _stack_flops(cfg.block, F) + 2 * 2 * F * x * d + 2 * 2 * d * d  # in/out projections, time MLP (once)
    if kind == "contact":
        f += 2 * F * (o * d + d * d)
    else:
        f += 2 * F * (o * d + d * (d // 2)) + 2 * F * (contact_dim(cfg) * d + d * (d - d // 2))
    return int(f)
