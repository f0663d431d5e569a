"""The treble-residual denoiser (paper §5.1, Fig. 2a; reference §3.1).

    z_i   = In(x_i)                       per-frame Linear(168 → D) of the (42, 4) motion
    t_tok = MLP(PE[t])                    Linear → SiLU → Linear on the sinusoidal table at t
    for k in (left, right, interaction):  ONE shared post-LN decoder stack, run once per text
        s_k  = [t_tok, CLS_k, z_1..z_F] + PE[0..F+1]
        o_k  = Dec(s_k, memory = TextProj(text_k))[2:]
    x̂0   = Out(z + o_L + o_R + o_I)      the model predicts x0

The three passes share weights, so they run as one decoder call on a 3B batch. Classifier-free
guidance uses one learned null text embedding (D,) shared by the three branches, as the reference's
single (1,1,D) null (§3.1); ``drop_BxK`` selects, per sample and branch, whether that branch's text
tokens are all replaced by it (the branch's CLS token still tells the branches apart).

Initialisation follows reference §3.1: every Linear N(0, 0.02) with zero bias (decoder layers
included; q/k/v keep PyTorch's packed in_proj xavier init, see ``layers.REFERENCE_LINEAR_INIT``);
CLS tokens and the null embedding N(0, 1).

Parameter counts with 768-wide text features reproduce paper Table C (tests/test_dit.py).
"""

from __future__ import annotations


from dataclasses import dataclass

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.models.ladder import named_sizes
from handx_jax.models.layers import (REFERENCE_LINEAR_INIT, DecoderLayer, Dropout, packed_in_proj_init,
                                     sinusoidal_table, with_branch_token)
from handx_jax.models.shape_cache import per_config

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
    **{name: DiTConfig(layers=L, dim=d, heads=H, ff=F) for name, (L, d, H, F) in named_sizes().items()},
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
    """``__call__`` is the training/reference forward. Sampling splits it (issue 15): the text memory
    is fixed across denoising steps, so :meth:`encode` projects it and computes every layer's
    cross-attention keys/values once per sample, and :meth:`denoise` runs one step from them; its
    last ``null_rows`` samples are unconditional (null text on all branches, a one-token memory)."""

    cfg: DiTConfig
    dtype: jnp.dtype = jnp.float32

    def setup(self):
        c = self.cfg
        dense = lambda n: nn.Dense(n, dtype=self.dtype, kernel_init=REFERENCE_LINEAR_INIT)  # noqa: E731
        self.input_proj = dense(c.dim)
        self.time_mlp_1 = dense(c.dim)
        self.time_mlp_2 = dense(c.dim)
        self.text_proj = dense(c.dim)
        self.output_proj = dense(c.motion_features)
        self.cls = self.param("cls", nn.initializers.normal(1.0), (NUM_BRANCHES, c.dim))
        self.null_text = self.param("null_text", nn.initializers.normal(1.0), (c.dim,))
        self.embed_drop = Dropout(c.dropout)
        for i in range(c.layers):  # names layer0..: the parameter tree of the original compact module
            setattr(self, f"layer{i}", DecoderLayer(c.dim, c.heads, c.ff, c.dropout, self.dtype,
                                                     kernel_init=REFERENCE_LINEAR_INIT, qkv_init=packed_in_proj_init))
        self.pe = jnp.asarray(sinusoidal_table(c.max_len, c.dim))

    def _layers(self):
        return [getattr(self, f"layer{i}") for i in range(self.cfg.layers)]

    def _memory(self, text_KxBxLxDt, text_mask_KxBxL, drop_BxK):
        """Projected text (K·B, L, D) and its key mask (K·B, 1, 1, L); dropped texts become the null
        embedding, all valid."""
        K, B, L = text_mask_KxBxL.shape
        mem = self.text_proj(text_KxBxLxDt)  # (K, B, L, D)
        drop_KxB = jnp.transpose(drop_BxK).astype(bool)
        mem = jnp.where(drop_KxB[..., None, None], self.null_text.astype(mem.dtype), mem)
        valid = jnp.where(drop_KxB[..., None], True, text_mask_KxBxL.astype(bool))
        return mem.reshape(K * B, L, -1), valid.reshape(K * B, 1, 1, L)

    def _decode(self, x_BxFxJxC, t_B, kvs, key_mask, *, deterministic, null_rows=0, null_repeats=False):
        """The treble-residual stack. Sequences are branch-major per group: the B − null_rows
        conditional samples' K branches, then the null rows' (so each group is one slice).

        ``null_repeats``: the null rows repeat the conditional rows exactly (same x and t, as
        classifier-free guidance stacks them). The two groups' sequences then differ only from the
        first cross-attention on, so the input projection and the first layer's self-attention
        block run once, on the conditional rows, and are copied (issue 15).

        Forward only (``deterministic``), a sample's three branch sequences [time, class_k, frames]
        differ in their class token alone until layer 0's self-attention mixes it in, so that block
        runs on the shared tokens once per sample (``DecoderLayer.branch_self_block``): DDIM + CFG
        2.0-2.5% faster per step at paper-4L (docs/results/perf_cpu.json, branch_sharing_2026_11_25)."""
        c = self.cfg
        B, F = x_BxFxJxC.shape[:2]
        nc = B - null_rows
        if null_repeats:
            if null_rows != nc:
                raise ValueError(f"null_repeats needs as many null rows as conditional ones; got {null_rows} of {B}")
            x_BxFxJxC, t_B = x_BxFxJxC[:nc], t_B[:nc]
        n_in = x_BxFxJxC.shape[0]
        z_BxFxD = self.input_proj(x_BxFxJxC.reshape(n_in, F, c.motion_features))
        t_tok = self.time_mlp_2(nn.silu(self.time_mlp_1(self.pe[t_B])))[:, None]  # (B, 1, D)
        pe = self.pe[: F + 2].astype(z_BxFxD.dtype)
        cls_KxD = self.cls.astype(z_BxFxD.dtype) + pe[1]
        # every token but the class token, the same in the three branches: (n_in, F+1, D)
        h_NxSxD = jnp.concatenate([t_tok, z_BxFxD], axis=1) + jnp.concatenate([pe[:1], pe[2:]])
        # (K, n_in, F+2, D) -> rows branch-major per group: the conditional samples', then the null rows'
        group = lambda a_KxNxSxD: jnp.concatenate(  # noqa: E731
            [a_KxNxSxD[:, :nc].reshape(-1, F + 2, c.dim), a_KxNxSxD[:, nc:].reshape(-1, F + 2, c.dim)])
        layers = self._layers()
        if deterministic:
            seq = group(layers[0].branch_self_block(h_NxSxD, cls_KxD))
        else:
            seq = group(with_branch_token(h_NxSxD, cls_KxD))  # the three branch sequences in full
            seq = layers[0].self_block(self.embed_drop(seq, deterministic=False), deterministic=False)
        if null_repeats:  # the null group is empty so far: its layer-0 self-attention block is the conditional one's
            seq = jnp.concatenate([seq, seq])
        for i, (layer, kv) in enumerate(zip(layers, kvs)):
            cross = dict(deterministic=deterministic, kv=kv, null_mem_D=self.null_text,
                         null_rows=NUM_BRANCHES * null_rows)
            if i > 0:
                seq = layer.self_block(seq, deterministic=deterministic)
            seq = layer.cross_block(seq, None, key_mask, **cross)
        if null_repeats:
            z_BxFxD = jnp.concatenate([z_BxFxD, z_BxFxD])
        out_cond = seq[: NUM_BRANCHES * nc].reshape(NUM_BRANCHES, nc, F + 2, c.dim)
        out_null = seq[NUM_BRANCHES * nc:].reshape(NUM_BRANCHES, null_rows, F + 2, c.dim)
        out_KxBxFxD = jnp.concatenate([out_cond, out_null], axis=1)[:, :, 2:]
        # The treble residual, z + o_L + o_R + o_I, as explicit adds: written as a reduce over the branch
        # axis XLA CPU fused it into the output projection's dot, which then took 14.6 ms of a 0.65 s
        # DDIM + CFG step (paper-4L, batch 32) against 1.8 ms with adds (issue 15).
        h = z_BxFxD
        for k in range(NUM_BRANCHES):
            h = h + out_KxBxFxD[k]
        x0 = self.output_proj(h)
        return x0.reshape(B, F, c.joints, c.channels).astype(jnp.float32)

    def __call__(self, x_BxFxJxC, t_B, text_KxBxLxDt, text_mask_KxBxL, drop_BxK, *, deterministic: bool = True):
        mem, key_mask = self._memory(text_KxBxLxDt, text_mask_KxBxL, drop_BxK)
        kvs = [layer.memory_kv(mem) for layer in self._layers()]
        return self._decode(x_BxFxJxC, t_B, kvs, key_mask, deterministic=deterministic)

    def encode(self, text_KxBxLxDt, text_mask_KxBxL):
        """What :meth:`denoise` needs of the (conditional) text, computed once per sample:
        {"kv": per layer (keys, values) (K·B, L, H, D/H), "key_mask": (K·B, 1, 1, L)}."""
        B = text_mask_KxBxL.shape[1]
        mem, key_mask = self._memory(text_KxBxLxDt, text_mask_KxBxL, jnp.zeros((B, NUM_BRANCHES), bool))
        return {"kv": [layer.memory_kv(mem) for layer in self._layers()], "key_mask": key_mask}

    def denoise(self, x_NxFxJxC, t_N, memory, null_rows: int = 0, null_repeats: bool = False):
        """x̂0 for N = B + null_rows samples (deterministic): the first B with ``memory`` from
        :meth:`encode` (B samples), the last ``null_rows`` unconditional (null text on all branches).
        ``null_repeats`` promises that the null rows' x and t repeat the first B rows' (guidance's
        [x; x] batch), so the work before the first cross-attention is done once (see ``_decode``)."""
        if x_NxFxJxC.shape[0] - null_rows == 0:
            memory = {"kv": [None] * self.cfg.layers, "key_mask": None}
        return self._decode(x_NxFxJxC, t_N, memory["kv"], memory["key_mask"], deterministic=True,
                            null_rows=null_rows, null_repeats=null_repeats)


def init_denoiser(cfg: DiTConfig, rng: jax.Array, text_len: int = 8):
    model = TrebleDenoiser(cfg)
    x = jnp.zeros((1, cfg.frames, cfg.joints, cfg.channels))
    text = jnp.zeros((NUM_BRANCHES, 1, text_len, cfg.text_dim))
    mask = jnp.ones((NUM_BRANCHES, 1, text_len), bool)
    # jitted: one XLA program rather than one compile per initialiser op (same values, seconds less on CPU)
    t, drop = jnp.zeros((1,), jnp.int32), jnp.zeros((1, NUM_BRANCHES), bool)
    return model, jax.jit(model.init)(rng, x, t, text, mask, drop)


@per_config
def param_count(cfg: DiTConfig) -> int:
    """Trainable parameters, from shapes only (no memory spent). Cached per config (frozen, hashable):
    tracing the init costs ~0.5-0.8 CPU-s at paper sizes, and a run's record, its sweep row and ``handx
    params`` each ask again."""
    shapes = jax.eval_shape(lambda r: init_denoiser(cfg, r)[1], jax.random.PRNGKey(0))
    return int(sum(int(np.prod(s.shape)) for s in jax.tree_util.tree_leaves(shapes)))


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
