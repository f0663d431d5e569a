"""Shared transformer blocks (flax.linen), used by the evaluator and the generators.

The reference models are PyTorch ``nn.TransformerEncoder/Decoder`` stacks with post-LN, GELU and
dropout 0.1 (reference §3.1, §5.1); these blocks reproduce that layout so parameter counts match
(Linear weights + biases, LayerNorm scale + bias).
"""

from __future__ import annotations

from typing import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

Initializer = Callable
FLAX_KERNEL_INIT = nn.linear.default_kernel_init  # lecun_normal: what Dense and attention use by default
# Reference §3.1: every nn.Linear of the denoiser gets N(0, 0.02) weights and zero bias (flax biases start
# at zero already). PyTorch's MultiheadAttention keeps q/k/v in one packed (3D, D) in_proj_weight, a plain
# Parameter rather than an nn.Linear, so that init pass leaves it at its own xavier_uniform_ init
# (fan_in D, fan_out 3D); its out_proj is an nn.Linear and gets N(0, 0.02).
REFERENCE_LINEAR_INIT = nn.initializers.normal(0.02)


def packed_in_proj_init(key, shape, dtype=jnp.float32):
    """xavier_uniform_ of PyTorch's packed (3D, D) in_proj_weight, for one of q/k/v shaped (D, H, D/H)."""
    d = shape[0]
    bound = float(np.sqrt(6.0 / (d + 3 * d)))
    return jax.random.uniform(key, shape, dtype, -bound, bound)


def sinusoidal_table(max_len: int, dim: int) -> np.ndarray:
    """The transformer PE table (max_len, dim): sin on even dims, cos on odd, freq 10000^(−2k/D)."""
    pos = np.arange(max_len, dtype=np.float64)[:, None]
    div = np.exp(np.arange(0, dim, 2, dtype=np.float64) * (-np.log(10000.0) / dim))
    pe = np.zeros((max_len, dim), np.float64)
    pe[:, 0::2] = np.sin(pos * div)
    pe[:, 1::2] = np.cos(pos * div[: dim // 2])
    return pe.astype(np.float32)


def attention_mask(q_valid_BxQ, k_valid_BxK):
    """Boolean mask (B, 1, Q, K) for flax attention: True where a query may attend to a key."""
    return q_valid_BxQ[:, None, :, None] & k_valid_BxK[:, None, None, :]


class FeedForward(nn.Module):
    dim: int
    ff: int
    dropout: float = 0.1
    dtype: jnp.dtype = jnp.float32
    kernel_init: Initializer = FLAX_KERNEL_INIT

    @nn.compact
    def __call__(self, x, *, deterministic: bool):
        h = nn.gelu(nn.Dense(self.ff, dtype=self.dtype, kernel_init=self.kernel_init, name="lin1")(x),
                    approximate=False)
        h = nn.Dropout(self.dropout)(h, deterministic=deterministic)
        return nn.Dense(self.dim, dtype=self.dtype, kernel_init=self.kernel_init, name="lin2")(h)


class EncoderLayer(nn.Module):
    """Post-LN self-attention block: x = LN(x + SA(x)); x = LN(x + FF(x))."""

    dim: int
    heads: int
    ff: int
    dropout: float = 0.1
    dtype: jnp.dtype = jnp.float32

    @nn.compact
    def __call__(self, x_BxLxD, mask_Bx1xLxL=None, *, deterministic: bool):
        a = nn.MultiHeadDotProductAttention(num_heads=self.heads, dtype=self.dtype, dropout_rate=self.dropout,
                                            deterministic=deterministic, name="self_attn")(x_BxLxD, mask=mask_Bx1xLxL)
        x = nn.LayerNorm(epsilon=1e-5, dtype=self.dtype, name="norm1")(
            x_BxLxD + nn.Dropout(self.dropout)(a, deterministic=deterministic))
        f = FeedForward(self.dim, self.ff, self.dropout, self.dtype, name="ff")(x, deterministic=deterministic)
        return nn.LayerNorm(epsilon=1e-5, dtype=self.dtype, name="norm2")(
            x + nn.Dropout(self.dropout)(f, deterministic=deterministic))


class DecoderLayer(nn.Module):
    """Post-LN decoder block: self-attention, cross-attention to memory, feed-forward.

    ``kernel_init`` initialises the feed-forward and attention-output kernels, ``qkv_init`` the q/k/v
    kernels (flax defaults; the denoiser passes the reference's, see ``REFERENCE_LINEAR_INIT``).
    """

    dim: int
    heads: int
    ff: int
    dropout: float = 0.1
    dtype: jnp.dtype = jnp.float32
    kernel_init: Initializer = FLAX_KERNEL_INIT
    qkv_init: Initializer = FLAX_KERNEL_INIT

    @nn.compact
    def __call__(self, x_BxLxD, mem_BxMxD, self_mask=None, cross_mask=None, *, deterministic: bool):
        drop = lambda h: nn.Dropout(self.dropout)(h, deterministic=deterministic)  # noqa: E731
        a = nn.MultiHeadDotProductAttention(num_heads=self.heads, dtype=self.dtype, dropout_rate=self.dropout,
                                            deterministic=deterministic, kernel_init=self.qkv_init,
                                            out_kernel_init=self.kernel_init, name="self_attn")(x_BxLxD, mask=self_mask)
        x = nn.LayerNorm(epsilon=1e-5, dtype=self.dtype, name="norm1")(x_BxLxD + drop(a))
        c = nn.MultiHeadDotProductAttention(num_heads=self.heads, dtype=self.dtype, dropout_rate=self.dropout,
                                            deterministic=deterministic, kernel_init=self.qkv_init,
                                            out_kernel_init=self.kernel_init, name="cross_attn")(x, mem_BxMxD,
                                                                                                 mask=cross_mask)
        x = nn.LayerNorm(epsilon=1e-5, dtype=self.dtype, name="norm2")(x + drop(c))
        f = FeedForward(self.dim, self.ff, self.dropout, self.dtype, self.kernel_init, name="ff")(
            x, deterministic=deterministic)
        return nn.LayerNorm(epsilon=1e-5, dtype=self.dtype, name="norm3")(x + drop(f))


def count_params(params) -> int:
    import jax

    return int(sum(np.prod(p.shape) for p in jax.tree_util.tree_leaves(params)))
