"""Shared transformer blocks (flax.linen), used by the evaluator and the generators.

The reference models are PyTorch ``nn.TransformerEncoder/Decoder`` stacks with post-LN, GELU and
dropout 0.1 (reference §3.1, §5.1); these blocks reproduce that layout so parameter counts match
(Linear weights + biases, LayerNorm scale + bias).

Attention keeps the parameter tree of ``flax.linen.MultiHeadDotProductAttention`` (``query``/``key``/
``value`` kernels (D, H, D/H), ``out`` kernel (H, D/H, D)), so checkpoints written before this module
existed load unchanged; it is written out here so that the key/value projections of a fixed memory
can be computed once and reused (the denoiser's text memory across all sampling steps, issue 15).

Dropout draws its masks from a counter-based hash (murmur3's 32-bit finaliser of the element index
mixed with a per-call seed) instead of ``jax.random``: on a 2-core CPU the threefry bits of the
denoiser's ~53 M dropout elements per training step cost ~22% of the step, the hash ~3% (measured:
benchmarks/diffusion.py, docs/results/perf_cpu.json). The seed of each call still comes from the
module's ``dropout`` rng stream, so masks are a pure function of (rng, call, element).
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
    """Boolean mask (B, 1, Q, K) for attention: True where a query may attend to a key."""
    return q_valid_BxQ[:, None, :, None] & k_valid_BxK[:, None, None, :]


def _fmix32(h):
    """murmur3's 32-bit finaliser: a bijective avalanche mix (every output bit depends on every input bit)."""
    h = h ^ (h >> 16)
    h = h * jnp.uint32(0x85EBCA6B)
    h = h ^ (h >> 13)
    h = h * jnp.uint32(0xC2B2AE35)
    return h ^ (h >> 16)


def keep_mask(seed_u32, shape, rate: float):
    """Boolean dropout mask: each element kept with probability 1 − rate (to 2⁻³² resolution).

    Element i gets fmix32(fmix32(i·φ ⊕ seed)) as its 32 random bits (φ the golden-ratio constant);
    neighbouring elements and neighbouring seeds decorrelate through the two avalanche rounds.
    """
    n = int(np.prod(shape))
    if n >= 2 ** 32:
        raise ValueError(f"dropout over {n} elements: the counter hash covers at most 2^32 per call")
    idx = jax.lax.iota(jnp.uint32, n).reshape(shape)
    bits = _fmix32(_fmix32((idx * jnp.uint32(0x9E3779B1)) ^ seed_u32))
    return bits >= jnp.uint32(min(int(round(rate * 2.0 ** 32)), 2 ** 32 - 1))


class Dropout(nn.Module):
    """Inverted dropout (as ``nn.Dropout``) with hash-generated masks; ``broadcast_dims`` share a mask."""

    rate: float
    broadcast_dims: tuple[int, ...] = ()

    @nn.compact
    def __call__(self, x, *, deterministic: bool):
        if deterministic or self.rate == 0.0:
            return x
        seed = jax.random.bits(self.make_rng("dropout"), (), jnp.uint32)
        shape = tuple(1 if d in self.broadcast_dims or d - x.ndim in self.broadcast_dims else n
                      for d, n in enumerate(x.shape))
        keep = keep_mask(seed, shape, self.rate)
        return jnp.where(keep, x / jnp.asarray(1.0 - self.rate, x.dtype), jnp.zeros((), x.dtype))


def _heads_major(x_BxSxHxK):
    """(B, S, H, K) ↔ (B, H, S, K), so attention's products are plain batched matmuls over (B, H)."""
    return jnp.swapaxes(x_BxSxHxK, 1, 2)


def with_branch_token(h_NxSxD, c_KxD):
    """The K·N branch sequences, (K, N, S + 1, D): each shared sequence ``h_n`` with branch token ``c_k``
    inserted at position 1 (the denoiser's [time, class_k, frames])."""
    K, (N, S, D) = c_KxD.shape[0], h_NxSxD.shape
    return jnp.concatenate([jnp.broadcast_to(h_NxSxD[None, :, :1], (K, N, 1, D)),
                            jnp.broadcast_to(c_KxD[:, None, None], (K, N, 1, D)),
                            jnp.broadcast_to(h_NxSxD[None, :, 1:], (K, N, S - 1, D))], axis=2)


class Attention(nn.Module):
    """Multi-head dot-product attention with flax MultiHeadDotProductAttention's parameters and maths
    (query scaled by 1/√(D/H), float32 softmax, attention-weight dropout shared over batch and heads)."""

    dim: int
    heads: int
    dropout: float = 0.1
    dtype: jnp.dtype = jnp.float32
    qkv_init: Initializer = FLAX_KERNEL_INIT
    out_init: Initializer = FLAX_KERNEL_INIT

    def setup(self):
        hd = (self.heads, self.dim // self.heads)
        self.query = nn.DenseGeneral(hd, dtype=self.dtype, kernel_init=self.qkv_init)
        self.key = nn.DenseGeneral(hd, dtype=self.dtype, kernel_init=self.qkv_init)
        self.value = nn.DenseGeneral(hd, dtype=self.dtype, kernel_init=self.qkv_init)
        self.out = nn.DenseGeneral(self.dim, axis=(-2, -1), dtype=self.dtype, kernel_init=self.out_init)
        self.weight_drop = Dropout(self.dropout, broadcast_dims=(0, 1))

    def kv(self, mem_BxMxD):
        """Keys and values (B, M, H, D/H) of a memory: computed once when the memory is fixed."""
        return self.key(mem_BxMxD), self.value(mem_BxMxD)

    def single_token(self, mem_D):
        """The output for a memory of one token (or of copies of one token): softmax weights are 1,
        so every query gets out(value(m)), whatever the query."""
        return self.out(self.value(mem_D))

    def branch_self_attention(self, h_NxSxD, c_KxD):
        """Self-attention (forward only, no mask) of the K·N sequences ``h_n`` with branch token ``c_k``
        inserted at position 1, as (K, N, S + 1, D), computed from the N shared sequences once.

        The denoiser's first layer sees three branch sequences per sample that differ only in their
        class token (§3.1: [time, class_k, frames]). So the shared tokens' queries, keys, values and
        their attention to one another are the same in all three: with LSE_i the log-sum-exp of query
        i's logits over the shared keys and A_i its attention output over them, adding branch k's key
        with logit t_ik gives exactly A_i + β_ik (v_k − A_i), β_ik = sigmoid(t_ik − LSE_i), per head.
        The class-token rows attend to the shared keys and their own. Equal to running the K·N
        sequences through ``__call__`` up to float rounding (tests/test_perf_paths.py)."""
        scale = jnp.sqrt(self.dim // self.heads).astype(self.dtype)
        q_s, (k_s, v_s) = self.query(h_NxSxD) / scale, self.kv(h_NxSxD)  # (N, S, H, K)
        q_c, (k_c, v_c) = self.query(c_KxD) / scale, self.kv(c_KxD)  # (K, H, K)
        logits = (_heads_major(q_s) @ jnp.transpose(k_s, (0, 2, 3, 1))).astype(jnp.float32)  # (N, H, S, S)
        top = jnp.max(logits, axis=-1, keepdims=True)
        e = jnp.exp(logits - top)
        z = jnp.sum(e, axis=-1, keepdims=True)
        a_NxSxHxK = _heads_major((e.astype(self.dtype) @ _heads_major(v_s)) / z.astype(self.dtype))
        lse_NxSxH = jnp.swapaxes((top + jnp.log(z))[..., 0], 1, 2)
        t_KxNxSxH = jnp.einsum("nshd,khd->knsh", q_s, k_c).astype(jnp.float32)
        beta = jax.nn.sigmoid(t_KxNxSxH - lse_NxSxH).astype(self.dtype)[..., None]
        out_s = a_NxSxHxK + beta * (v_c[:, None, None] - a_NxSxHxK)  # (K, N, S, H, K)
        # the class-token queries: S shared keys and their own
        K, N, S = c_KxD.shape[0], h_NxSxD.shape[0], h_NxSxD.shape[1]
        l_c = jnp.einsum("khd,nshd->knhs", q_c, k_s)
        l_own = jnp.broadcast_to(jnp.sum(q_c * k_c, axis=-1)[:, None, :, None], (K, N, self.heads, 1))
        w = jax.nn.softmax(jnp.concatenate([l_c, l_own], axis=-1).astype(jnp.float32)).astype(self.dtype)
        out_c = jnp.einsum("knhs,nshd->knhd", w[..., :S], v_s) + w[..., S:] * v_c[:, None]
        return self.out(jnp.concatenate([out_s[:, :, :1], out_c[:, :, None], out_s[:, :, 1:]], axis=2))

    def __call__(self, x_BxQxD, kv=None, mask_Bx1xQxK=None, *, deterministic: bool):
        """Attend from x to ``kv`` (keys, values) or, if None, to x itself (self-attention)."""
        q_BxQxHxK = self.query(x_BxQxD) / jnp.sqrt(self.dim // self.heads).astype(self.dtype)
        k_BxMxHxK, v_BxMxHxK = self.kv(x_BxQxD) if kv is None else kv
        # Same values either way; the layout is chosen for speed on XLA CPU (issue 15). Forward only
        # (deterministic: sampling, evaluation) the products run as batched matmuls over (batch, head):
        # the DDIM + CFG sampler 4.4-4.9% faster. Under autodiff that layout's backward cost a training
        # step 2.7-4.6% (docs/results/perf_cpu.json, attention_layout_2026_11_24), so training keeps the einsums.
        if deterministic:
            logits = _heads_major(q_BxQxHxK) @ jnp.transpose(k_BxMxHxK, (0, 2, 3, 1))
        else:
            logits = jnp.einsum("bqhd,bkhd->bhqk", q_BxQxHxK, k_BxMxHxK)
        if mask_Bx1xQxK is not None:
            logits = jnp.where(mask_Bx1xQxK, logits, jnp.finfo(logits.dtype).min)
        w_BxHxQxM = jax.nn.softmax(logits.astype(jnp.float32)).astype(self.dtype)
        w_BxHxQxM = self.weight_drop(w_BxHxQxM, deterministic=deterministic)
        if deterministic:
            return self.out(_heads_major(w_BxHxQxM @ _heads_major(v_BxMxHxK)))
        return self.out(jnp.einsum("bhqk,bkhd->bqhd", w_BxHxQxM, v_BxMxHxK))


def gelu_erf(x):
    """Exact (erf) GELU written as PyTorch's CPU kernel computes it, 0.5·x·(1 + erf(x/√2)).

    ``jax.nn.gelu(approximate=False)`` is the same function through ``erfc``, whose XLA CPU expansion
    (two branches with an exp each) cost twice as much: forward and backward of a (96, 62, 1024)
    activation took 17.8-19.7 ms against 9.3-11.1 ms with erf, and a feed-forward block at the DDIM +
    CFG sampler's shapes 79-80 ms against 70-73 (docs/results/perf_cpu.json, gelu_2026_11_24; whole
    steps gain less than this machine's noise). The two agree to 1e-6 absolute on [-12, 12]
    (tests/test_perf_paths.py).
    """
    return 0.5 * x * (1.0 + jax.lax.erf(x * jnp.asarray(1.0 / np.sqrt(2.0), x.dtype)))


class FeedForward(nn.Module):
    dim: int
    ff: int
    dropout: float = 0.1
    dtype: jnp.dtype = jnp.float32
    kernel_init: Initializer = FLAX_KERNEL_INIT

    @nn.compact
    def __call__(self, x, *, deterministic: bool):
        h = gelu_erf(nn.Dense(self.ff, dtype=self.dtype, kernel_init=self.kernel_init, name="lin1")(x))
        h = Dropout(self.dropout)(h, deterministic=deterministic)
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
        a = Attention(self.dim, self.heads, self.dropout, self.dtype, name="self_attn")(
            x_BxLxD, None, mask_Bx1xLxL, deterministic=deterministic)
        x = nn.LayerNorm(epsilon=1e-5, dtype=self.dtype, name="norm1")(
            x_BxLxD + Dropout(self.dropout)(a, deterministic=deterministic))
        f = FeedForward(self.dim, self.ff, self.dropout, self.dtype, name="ff")(x, deterministic=deterministic)
        return nn.LayerNorm(epsilon=1e-5, dtype=self.dtype, name="norm2")(
            x + Dropout(self.dropout)(f, deterministic=deterministic))


class DecoderLayer(nn.Module):
    """Post-LN decoder block: self-attention, cross-attention to memory, feed-forward.

    The memory may enter as its cross-attention keys/values ``kv`` (from :meth:`memory_kv`), so a
    fixed memory is projected once. The last ``null_rows`` rows of x attend to the one-token memory
    ``null_mem_D`` (the classifier-free-guidance null text): their cross-attention output is one
    vector, computed without queries or scores. The block is :meth:`self_block` then
    :meth:`cross_block`, callable apart so a caller whose rows repeat can run the first half once.

    ``kernel_init`` initialises the feed-forward and attention-output kernels, ``qkv_init`` the q/k/v
    kernels (flax defaults; the denoiser passes the reference's, see ``REFERENCE_LINEAR_INIT``).
    """

    dim: int
    heads: int
    ff_dim: int
    dropout: float = 0.1
    dtype: jnp.dtype = jnp.float32
    kernel_init: Initializer = FLAX_KERNEL_INIT
    qkv_init: Initializer = FLAX_KERNEL_INIT

    def setup(self):
        attn = lambda: Attention(self.dim, self.heads, self.dropout, self.dtype, self.qkv_init,  # noqa: E731
                                 self.kernel_init)
        self.self_attn, self.cross_attn = attn(), attn()
        self.ff = FeedForward(self.dim, self.ff_dim, self.dropout, self.dtype, self.kernel_init)
        self.norm1, self.norm2, self.norm3 = (nn.LayerNorm(epsilon=1e-5, dtype=self.dtype) for _ in range(3))
        self.drop1, self.drop2, self.drop3 = (Dropout(self.dropout) for _ in range(3))

    def memory_kv(self, mem_BxMxD):
        return self.cross_attn.kv(mem_BxMxD)

    def self_block(self, x_BxSxD, self_mask=None, *, deterministic: bool):
        a = self.self_attn(x_BxSxD, None, self_mask, deterministic=deterministic)
        return self.norm1(x_BxSxD + self.drop1(a, deterministic=deterministic))

    def branch_self_block(self, h_NxSxD, c_KxD):
        """:meth:`self_block` (forward only) of the K·N sequences ``h_n`` with ``c_k`` inserted at
        position 1, from the shared tokens (``Attention.branch_self_attention``): (K, N, S + 1, D)."""
        return self.norm1(with_branch_token(h_NxSxD, c_KxD) + self.self_attn.branch_self_attention(h_NxSxD, c_KxD))

    def cross_block(self, x, mem_BxMxD=None, cross_mask=None, *, deterministic: bool, kv=None, null_mem_D=None,
                    null_rows: int = 0):
        """Cross-attention and feed-forward, each with its residual and norm."""
        n_mem = x.shape[0] - null_rows
        parts = []
        if n_mem:
            kv = self.cross_attn.kv(mem_BxMxD) if kv is None else kv
            parts.append(self.cross_attn(x[:n_mem], kv, cross_mask, deterministic=deterministic))
        if null_rows:
            c_D = self.cross_attn.single_token(null_mem_D).astype(x.dtype)
            parts.append(jnp.broadcast_to(c_D, (null_rows,) + x.shape[1:]))
        c = parts[0] if len(parts) == 1 else jnp.concatenate(parts)
        x = self.norm2(x + self.drop2(c, deterministic=deterministic))
        f = self.ff(x, deterministic=deterministic)
        return self.norm3(x + self.drop3(f, deterministic=deterministic))

    def __call__(self, x_BxSxD, mem_BxMxD=None, self_mask=None, cross_mask=None, *, deterministic: bool,
                 kv=None, null_mem_D=None, null_rows: int = 0):
        x = self.self_block(x_BxSxD, self_mask, deterministic=deterministic)
        return self.cross_block(x, mem_BxMxD, cross_mask, deterministic=deterministic, kv=kv, null_mem_D=null_mem_D,
                                null_rows=null_rows)


def count_params(params) -> int:
    return int(sum(np.prod(p.shape) for p in jax.tree_util.tree_leaves(params)))
