"""The text-prefix motion LM, LLaMA-style (paper §5.2, Table 3/C; reference §4.5–4.6).

    slots   [ text_0 .. text_{Lp−1} | m_0 .. m_29, END ]        text padded to Lp; valid prefix first
    x       = TextProj(text) on text slots, Emb(token) on motion slots
    x      += Attn(RMSNorm(x)); x += SwiGLU(RMSNorm(x))          × layers, then a final RMSNorm
    logits  = Head(x) at the last valid text slot and motion slots 0..29 → targets m_0..m_29, END

- RMSNorm eps 1e-5; SwiGLU W3(silu(W1 x) ⊙ W2 x), hidden int(2·4D/3) rounded up to a multiple of 256;
  fused QKV Linear(D, 3D), out Linear(D, D); no biases except the text projection (§4.5).
- RoPE (base 10000) over ADJACENT pairs (x0,x1),(x2,x3),… of each head. Positions run over the whole
  sequence with the prefix included: text slot j has position j, motion slot k has position ℓ + k for
  a text of ℓ valid tokens, exactly as the reference's packed [text ℓ | motion | END | PAD] rows.
- Attention: a key is visible when it is valid and (causal, or both query and key are text): the
  prefix is bidirectional, motion is causal. Padded text slots are never keys.
- Token ids: codes 0..V−1, END = V, PAD = V+1; the embedding has V+2 rows, the untied head V+1 outputs.

Parameter counts with 768-wide text features reproduce Table C (tests/test_prefix_lm.py).
"""

from __future__ import annotations


import math
from dataclasses import dataclass

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.models.shape_cache import per_config

MOTION_TOKENS = 30  # 60 frames at temporal factor 2 (§4.1)


@dataclass(frozen=True)
class LMConfig:
    layers: int = 8
    dim: int = 512
    heads: int = 8
    nb_code: int = 1920  # REAL codebook size (e.g. 4375 for the nominal 4096)
    text_dim: int = 768
    rope_base: float = 10000.0
    max_motion: int = MOTION_TOKENS

    @property
    def hidden(self) -> int:
        h = int(2 * 4 * self.dim / 3)
        return 256 * math.ceil(h / 256)

    @property
    def end_id(self) -> int:
        return self.nb_code

    @property
    def pad_id(self) -> int:
        return self.nb_code + 1


# Named size ladder (paper Table C names by size); tiny/small are CPU presets.
PRESETS = {
    "tiny": LMConfig(layers=2, dim=64, heads=4),
    "small": LMConfig(layers=4, dim=128, heads=4),
    "8L-512": LMConfig(layers=8, dim=512, heads=8),
    "12L-768": LMConfig(layers=12, dim=768, heads=12),
    "16L-1024": LMConfig(layers=16, dim=1024, heads=16),
}


class RMSNorm(nn.Module):
    eps: float = 1e-5

    @nn.compact
    def __call__(self, x):
        g = self.param("scale", nn.initializers.ones, (x.shape[-1],))
        x32 = x.astype(jnp.float32)
        return (x32 * jax.lax.rsqrt(jnp.mean(x32 * x32, -1, keepdims=True) + self.eps)).astype(x.dtype) * g


def rope(x_BxSxHxK, pos_BxS, base: float):
    """Rotate adjacent pairs (x_{2i}, x_{2i+1}) by pos·base^(−2i/K) (the reference's complex view)."""
    K = x_BxSxHxK.shape[-1]
    inv = base ** (-jnp.arange(0, K, 2, dtype=jnp.float32) / K)
    ang = pos_BxS[..., None, None].astype(jnp.float32) * inv  # (B, S, 1, K/2)
    cos, sin = jnp.cos(ang), jnp.sin(ang)
    x = x_BxSxHxK.astype(jnp.float32).reshape(*x_BxSxHxK.shape[:-1], K // 2, 2)
    x0, x1 = x[..., 0], x[..., 1]
    out = jnp.stack([x0 * cos - x1 * sin, x0 * sin + x1 * cos], axis=-1)
    return out.reshape(x_BxSxHxK.shape).astype(x_BxSxHxK.dtype)


# Hand-written backward passes for the two places where autodiff keeps more than the maths needs.
# Measured on the `small` preset (batch 64, 128 text + 31 motion slots, compiled memory_analysis of one
# training step): XLA's temporary buffer was 1,069 MB, and at its peak (the start of the backward pass)
# 296 MB of it were 12 (B, H, S, S) float32 arrays (three per layer kept for the softmax's and the
# mask's backward) and ~400 MB the SwiGLU's (B, S, F) intermediates (five per layer: both projections,
# sigmoid, silu, the product). The backward passes below keep only what they need (the attention
# weights, one (B, H, S, S) array per layer; the two projections), recompute the cheap elementwise
# parts and apply the same chain rule as autodiff: 713 MB, the loss bit-identical and the gradients
# equal to float32 rounding (tests/test_prefix_lm.py compares them with autodiff of the plain forms).


def attend_reference(q_BxSxHxK, k_BxTxHxK, v_BxTxHxK, mask_BxSxT):
    """softmax(q·kᵀ/√K over the visible keys)·v with a float32 softmax; masked keys get −1e30."""
    att_BxHxSxT = jnp.einsum("bshk,bthk->bhst", q_BxSxHxK, k_BxTxHxK) / math.sqrt(q_BxSxHxK.shape[-1])
    att_BxHxSxT = jnp.where(mask_BxSxT[:, None], att_BxHxSxT.astype(jnp.float32), -1e30)
    p32_BxHxSxT = jax.nn.softmax(att_BxHxSxT, axis=-1)
    return jnp.einsum("bhst,bthk->bshk", p32_BxHxSxT.astype(v_BxTxHxK.dtype), v_BxTxHxK), p32_BxHxSxT


@jax.custom_vjp
def attend(q_BxSxHxK, k_BxTxHxK, v_BxTxHxK, mask_BxSxT):
    """``attend_reference``'s output; its backward keeps only the float32 weights (and q, k, v, mask)."""
    return attend_reference(q_BxSxHxK, k_BxTxHxK, v_BxTxHxK, mask_BxSxT)[0]


def _attend_fwd(q, k, v, mask):
    o, p32 = attend_reference(q, k, v, mask)
    return o, (q, k, v, mask, p32)


def _attend_bwd(res, do_BxSxHxK):
    q, k, v, mask, p32 = res
    dv = jnp.einsum("bhst,bshk->bthk", p32.astype(v.dtype), do_BxSxHxK)
    dp32 = jnp.einsum("bshk,bthk->bhst", do_BxSxHxK, v).astype(jnp.float32)
    pdp32 = p32 * dp32  # softmax's VJP, y·g − y·Σ(y·g), in the order autodiff of jax.nn.softmax computes it
    datt = pdp32 + p32 * jnp.sum(-pdp32, axis=-1, keepdims=True)
    datt = jnp.where(mask[:, None], datt, 0.0).astype(q.dtype) / math.sqrt(q.shape[-1])
    dq = jnp.einsum("bhst,bthk->bshk", datt, k)
    dk = jnp.einsum("bhst,bshk->bthk", datt, q)
    return dq, dk, dv, None


attend.defvjp(_attend_fwd, _attend_bwd)


@jax.custom_vjp
def swiglu(a_BxSxF, b_BxSxF):
    """silu(a) ⊙ b (the SwiGLU gate, §4.5); its backward keeps a and b and recomputes the sigmoid."""
    return nn.silu(a_BxSxF) * b_BxSxF


def _swiglu_fwd(a, b):
    return swiglu(a, b), (a, b)


def _swiglu_bwd(res, g):
    # `+ 0·g` ties the recomputation to the incoming gradient (for a finite g it adds ±0: a is unchanged).
    # Without it XLA on CPU computes every layer's sigmoid during the forward pass and keeps it alive
    # until the backward pass reaches that layer (+80 MB at the peak above); an optimization_barrier, as
    # jax.checkpoint uses, did not stop that on CPU (measured; nor did nn.remat on the blocks).
    a, b = res
    a = a + 0.0 * g
    s = jax.nn.sigmoid(a)
    du = g * b  # through silu(a) = a · s
    return du * s + (du * a) * (s * (1 - s)), g * (a * s)


swiglu.defvjp(_swiglu_fwd, _swiglu_bwd)


def _dense(n, name):
    return nn.Dense(n, use_bias=False, name=name)


class Block(nn.Module):
    cfg: LMConfig

    @nn.compact
    def __call__(self, x_BxSxD, pos_BxS, mask_BxSxK, kv=None, start=0):
        """``kv`` = (k, v) caches (B, Smax, H, K): this call's keys/values are written at slot ``start``
        and attention runs over the whole cache (its mask decides what is visible)."""
        c = self.cfg
        B, S, D = x_BxSxD.shape
        H, K = c.heads, D // c.heads
        qkv = _dense(3 * D, "qkv")(RMSNorm(name="attn_norm")(x_BxSxD))
        q, k, v = (t.reshape(B, S, H, K) for t in jnp.split(qkv, 3, axis=-1))
        q, k = rope(q, pos_BxS, c.rope_base), rope(k, pos_BxS, c.rope_base)
        if kv is not None:
            k = jax.lax.dynamic_update_slice(kv[0], k.astype(kv[0].dtype), (0, start, 0, 0))
            v = jax.lax.dynamic_update_slice(kv[1], v.astype(kv[1].dtype), (0, start, 0, 0))
            kv = (k, v)
        o = attend(q, k, v, mask_BxSxK).reshape(B, S, D)
        x = x_BxSxD + _dense(D, "out")(o)
        h = RMSNorm(name="mlp_norm")(x)
        h = swiglu(_dense(c.hidden, "w1")(h), _dense(c.hidden, "w2")(h))
        return x + _dense(D, "w3")(h), kv


class PrefixLM(nn.Module):
    cfg: LMConfig

    def setup(self):
        c = self.cfg
        self.text_proj = nn.Dense(c.dim, name="text_proj")  # the one layer with a bias (§4.5)
        self.embed = nn.Embed(c.nb_code + 2, c.dim, name="embed")
        self.blocks = [Block(c, name=f"layer{i}") for i in range(c.layers)]
        self.norm = RMSNorm(name="norm")
        self.head = _dense(c.nb_code + 1, "head")

    def hidden(self, x_BxSxD, pos_BxS, mask_BxSxK, cache=None, start=0):
        new = []
        for i, blk in enumerate(self.blocks):
            x_BxSxD, kv = blk(x_BxSxD, pos_BxS, mask_BxSxK, None if cache is None else cache[i], start)
            new.append(kv)
        return self.norm(x_BxSxD), (new if cache is not None else None)

    def embed_text(self, text_BxLxDt):
        return self.text_proj(text_BxLxDt)

    def embed_tokens(self, tok):
        return self.embed(tok)

    def logits(self, h):
        return self.head(h).astype(jnp.float32)

    def __call__(self, text_BxLxDt, text_mask_BxL, tokens_BxM):
        """Training forward: logits (B, M, V+1) of the M next-token predictions made from the last
        valid text slot and motion slots 0..M−2 (targets tokens_BxM[:, 0..M−1])."""
        x, pos, mask = prefix_inputs(self, text_BxLxDt, text_mask_BxL, tokens_BxM)
        h, _ = self.hidden(x, pos, mask)
        return self.logits(_prediction_states(h, text_mask_BxL, tokens_BxM.shape[1]))


def text_lengths(text_mask_BxL):
    return text_mask_BxL.astype(jnp.int32).sum(-1)


def slot_positions(text_mask_BxL, total_slots: int):
    """RoPE position of every slot: j on text slot j; ℓ + k on motion slot k (packed-row positions)."""
    Lp = text_mask_BxL.shape[1]
    s = jnp.arange(total_slots)[None]
    return jnp.where(s < Lp, s, text_lengths(text_mask_BxL)[:, None] + (s - Lp))


def attention_mask(text_mask_BxL, q_slots, total_slots: int):
    """(B, len(q_slots), total_slots): key valid and (causal in slots, or both text)."""
    Lp = text_mask_BxL.shape[1]
    k = jnp.arange(total_slots)
    key_valid = jnp.concatenate([text_mask_BxL.astype(bool),
                                 jnp.ones((text_mask_BxL.shape[0], total_slots - Lp), bool)], axis=1)
    q = jnp.asarray(q_slots)[:, None]
    vis = (k[None] <= q) | ((q < Lp) & (k[None] < Lp))
    return key_valid[:, None, :] & vis[None]


def prefix_inputs(model: PrefixLM, text_BxLxDt, text_mask_BxL, tokens_BxM):
    """Embedded slots, positions and the full-sequence mask for [text | tokens]."""
    Lp, M = text_mask_BxL.shape[1], tokens_BxM.shape[1]
    x = jnp.concatenate([model.embed_text(text_BxLxDt), model.embed_tokens(tokens_BxM)], axis=1)
    S = Lp + M
    return x, slot_positions(text_mask_BxL, S), attention_mask(text_mask_BxL, jnp.arange(S), S)


def _prediction_states(h_BxSxD, text_mask_BxL, M):
    """States that predict the M motion targets: the last valid text slot, then motion slots 0..M−2."""
    Lp = text_mask_BxL.shape[1]
    last = jnp.take_along_axis(h_BxSxD, (text_lengths(text_mask_BxL) - 1)[:, None, None], axis=1)
    return jnp.concatenate([last, h_BxSxD[:, Lp:Lp + M - 1]], axis=1)


def lm_loss(model: PrefixLM, params, text, text_mask, codes_BxN):
    """Cross-entropy from the last text position through END (§4.6): the input is the N codes and END
    (N + 1 motion slots, as the reference's rows), the targets the N codes then END; the END slot's own
    prediction (of PAD) is ignored, as ``ignore_index = PAD`` does."""
    c = model.cfg
    B, N = codes_BxN.shape
    tokens = jnp.concatenate([codes_BxN, jnp.full((B, 1), c.end_id, codes_BxN.dtype)], axis=1)
    logits = model.apply(params, text, text_mask, tokens)  # (B, N+1, V+1): targets codes, then END
    logp = jax.nn.log_softmax(logits, axis=-1)
    nll = -jnp.take_along_axis(logp, tokens[..., None], axis=-1)[..., 0]
    acc = jnp.mean((logits.argmax(-1) == tokens).astype(jnp.float32))
    return nll.mean(), {"acc": acc}


def init_lm(cfg: LMConfig, rng: jax.Array, text_len: int = 8):
    model = PrefixLM(cfg)
    # jitted: one XLA program instead of one dispatch (and compile) per initialiser op, 6.1 -> 2.1 s for the
    # tiny preset on CPU, with bit-identical values
    params = jax.jit(model.init)(rng, jnp.zeros((1, text_len, cfg.text_dim)), jnp.ones((1, text_len), bool),
                                 jnp.zeros((1, cfg.max_motion + 1), jnp.int32))
    return model, params


def param_counts(cfg: LMConfig) -> dict:
    """{params, params_non_embedding} from shapes only; non-embedding leaves out the token embedding
    table (the text projection and the head stay in, as nanoGPT-style counts do)."""
    total, embed = _param_counts(cfg)
    return {"params": total, "params_non_embedding": total - embed}


@per_config
def _param_counts(cfg: LMConfig) -> tuple[int, int]:
    """(all, embedding table), cached per config (frozen, hashable): tracing the init costs ~0.5 CPU-s."""
    shapes = jax.eval_shape(lambda r: init_lm(cfg, r)[1], jax.random.PRNGKey(0))["params"]
    n = lambda t: int(sum(int(np.prod(s.shape)) for s in jax.tree_util.tree_leaves(t)))  # noqa: E731
    return n(shapes), n(shapes["embed"])


def forward_flops(cfg: LMConfig, text_len: int, motion_slots: int = MOTION_TOKENS + 1) -> int:
    """Analytic forward FLOPs per sample (2 per multiply-add; matmuls and attention only).

    S = text_len + motion_slots (30 codes + END). Per layer: QKV + out 4·S·D², scores and mixing
    2·S²·D, SwiGLU 3·S·D·F. Plus the text projection (text_len·Dt·D), and the head over the
    ``motion_slots`` predicting states ((V+1)·D each). The frozen text encoder is counted apart.
    """
    D, S = cfg.dim, text_len + motion_slots
    macs = cfg.layers * (4 * S * D * D + 2 * S * S * D + 3 * S * D * cfg.hidden)
    macs += text_len * cfg.text_dim * D + motion_slots * D * (cfg.nb_code + 1)
    return int(2 * macs)
