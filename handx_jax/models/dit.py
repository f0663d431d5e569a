"""The treble-residual denoiser (paper §5.1, Fig. 2a; reference §3.1).

    z_i   = In(x_i)                       per-frame Linear(168 → D) of the (42, 4) motion
    t_tok = MLP(PE[t])                    Linear → SiLU → Linear on the sinusoidal table at t
    for k in (left, right, interaction):  ONE shared post-LN decoder stack, run once per text
        s_k  = [t_tok, CLS_k, z_1..z_F] + PE[0..F+1]
        o_k  = Dec(s_k, memory = TextProj(text_k))[2:]
    x̂0   = Out(z + o_L + o_R + o_I)      the model predicts x0

The three passes share weights, so they run as one decoder call on a 3B batch. Classifier-free
guidance uses a learned null text embedding per branch (reference: one (1,1,D) null embedding);
``drop_BxK`` selects, per sample and branch, whether the text is replaced by it.

Parameter counts with 768-wide text features reproduce paper Table C (tests/test_dit.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import flax.linen as nn
import jax
import jax.numpy as jnp

from handx_jax.models.layers import DecoderLayer, attention_mask, sinusoidal_table

NUM_BRANCHES = 3  # left, right, interaction


@dataclass(frozen=True)
class DiTConfig:
    layers: int = 8
    dim: int = 512
    heads: int = 8
    ff: int = 1024
    dropout: float = 0.1
    text_dim: int = 768
    frames: int = 60
    joints: int = 42
    channels: int = 4
    max_len: int = 5000  # sinusoidal table length (reference)

    @property
    def motion_features(self) -> int:
        return self.joints * self.channels


# Named size ladder (reference §3.3, paper Table B/C); "tiny" and "small" are CPU presets. The
# "L{layers}-d{dim}" names are the Table B points (heads dim/64, FF 4·dim), so a sweep over size is a
# sweep over names; the "paper-*" names are the reference's three configs (FF 1024).
PRESETS = {
    "tiny": DiTConfig(layers=2, dim=64, heads=4, ff=128),
    "small": DiTConfig(layers=4, dim=128, heads=4, ff=512),
    "paper-4L": DiTConfig(layers=4, dim=256, heads=4, ff=1024),
    "paper-8L": DiTConfig(layers=8, dim=512, heads=8, ff=1024),
    "paper-12L": DiTConfig(layers=12, dim=512, heads=8, ff=1024),
    **{f"L{L}-d{d}": DiTConfig(layers=L, dim=d, heads=H, ff=F)
       for L, d, H, F in [(2, 256, 4, 1024), (4, 256, 4, 1024), (4, 384, 6, 1536), (8, 384, 6, 1536),
                          (8, 512, 8, 2048), (12, 512, 8, 2048), (12, 768, 12, 3072)]},
}
SIZE_FIELDS = ("layers", "dim", "heads", "ff")


def size_name(cfg: DiTConfig, preset: str | None = None) -> str:
    """The name of ``cfg``'s size: ``preset`` if the sizes agree, else the first ladder name that
    matches, else ``L{layers}-d{dim}-H{heads}-F{ff}`` (so a run records the size it really has)."""
    size = lambda c: tuple(getattr(c, f) for f in SIZE_FIELDS)  # noqa: E731
    if preset in PRESETS and size(PRESETS[preset]) == size(cfg):
        return preset
    for name, c in PRESETS.items():
        if size(c) == size(cfg):
            return name
    return f"L{cfg.layers}-d{cfg.dim}-H{cfg.heads}-F{cfg.ff}"


class TrebleDenoiser(nn.Module):
    cfg: DiTConfig
    dtype: jnp.dtype = jnp.float32

    @nn.compact
    def __call__(self, x_BxFxJxC, t_B, text_KxBxLxDt, text_mask_KxBxL, drop_BxK, *, deterministic: bool = True):
        c = self.cfg
        B, F = x_BxFxJxC.shape[:2]
        pe = jnp.asarray(sinusoidal_table(c.max_len, c.dim))
        dense = lambda n, name: nn.Dense(n, dtype=self.dtype, kernel_init=nn.initializers.normal(0.02),  # noqa: E731
                                         name=name)
        z_BxFxD = dense(c.dim, "input_proj")(x_BxFxJxC.reshape(B, F, c.motion_features))
        t_tok = dense(c.dim, "time_mlp_1")(pe[t_B])
        t_tok = dense(c.dim, "time_mlp_2")(nn.silu(t_tok))[:, None]  # (B, 1, D)
        cls_KxD = self.param("cls", nn.initializers.normal(1.0), (NUM_BRANCHES, c.dim))
        null_D = self.param("null_text", nn.initializers.normal(1.0), (c.dim,))

        # Text memory per branch, with dropped samples replaced by the null embedding (all valid).
        mem = dense(c.dim, "text_proj")(text_KxBxLxDt)  # (K, B, L, D)
        drop_KxB = jnp.transpose(drop_BxK).astype(bool)
        mem = jnp.where(drop_KxB[..., None, None], null_D.astype(mem.dtype), mem)
        mem_valid = jnp.where(drop_KxB[..., None], True, text_mask_KxBxL.astype(bool))

        # Three branch sequences, stacked on the batch axis: (K·B, F+2, D).
        seq = jnp.concatenate([
            jnp.broadcast_to(t_tok[None], (NUM_BRANCHES, B, 1, c.dim)),
            jnp.broadcast_to(cls_KxD[:, None, None], (NUM_BRANCHES, B, 1, c.dim)).astype(z_BxFxD.dtype),
            jnp.broadcast_to(z_BxFxD[None], (NUM_BRANCHES, B, F, c.dim)),
        ], axis=2).reshape(NUM_BRANCHES * B, F + 2, c.dim)
        seq = seq + pe[: F + 2].astype(seq.dtype)
        seq = nn.Dropout(c.dropout)(seq, deterministic=deterministic)
        mem = mem.reshape(NUM_BRANCHES * B, -1, c.dim)
        mem_valid = mem_valid.reshape(NUM_BRANCHES * B, -1)
        self_valid = jnp.ones((NUM_BRANCHES * B, F + 2), bool)
        cross = attention_mask(self_valid, mem_valid)
        for i in range(c.layers):
            seq = DecoderLayer(c.dim, c.heads, c.ff, c.dropout, self.dtype, name=f"layer{i}")(
                seq, mem, None, cross, deterministic=deterministic)
        out_KxBxFxD = seq.reshape(NUM_BRANCHES, B, F + 2, c.dim)[:, :, 2:]
        h = z_BxFxD + out_KxBxFxD.sum(0)  # treble residual
        x0 = dense(c.motion_features, "output_proj")(h)
        return x0.reshape(B, F, c.joints, c.channels).astype(jnp.float32)


def init_denoiser(cfg: DiTConfig, rng: jax.Array, text_len: int = 8):
    model = TrebleDenoiser(cfg)
    x = jnp.zeros((1, cfg.frames, cfg.joints, cfg.channels))
    text = jnp.zeros((NUM_BRANCHES, 1, text_len, cfg.text_dim))
    mask = jnp.ones((NUM_BRANCHES, 1, text_len), bool)
    return model, model.init(rng, x, jnp.zeros((1,), jnp.int32), text, mask, jnp.zeros((1, NUM_BRANCHES), bool))


def param_count(cfg: DiTConfig) -> int:
    """Trainable parameters, from shapes only (no memory spent)."""
    model = TrebleDenoiser(cfg)
    shapes = jax.eval_shape(lambda r: init_denoiser(cfg, r)[1], jax.random.PRNGKey(0))
    del model
    return int(sum(int(jnp.prod(jnp.asarray(s.shape))) for s in jax.tree_util.tree_leaves(shapes)))


def forward_flops(cfg: DiTConfig, text_len: int) -> int:
    """Analytic forward FLOPs per sample (2 per multiply-add; matmuls and attention only).

    Per branch and layer: self-attention projections 4·S·D², scores and mixing 2·S²·D; cross-
    attention Q/out projections 2·S·D², K/V projections 2·L·D², scores and mixing 2·S·L·D; FF
    2·S·D·FF; S = F + 2 tokens, L = text tokens. Plus the input/output projections, the timestep
    MLP and the text projection of the three texts.
    """
    D, F, L = cfg.dim, cfg.frames, text_len
    S = F + 2
    per_layer = 4 * S * D * D + 2 * S * S * D + 2 * S * D * D + 2 * L * D * D + 2 * S * L * D + 2 * S * D * cfg.ff
    macs = NUM_BRANCHES * cfg.layers * per_layer
    macs += F * cfg.motion_features * D * 2  # input and output projections
    macs += 2 * D * D  # timestep MLP
    macs += NUM_BRANCHES * L * cfg.text_dim * D  # text projection
    return int(2 * macs)
