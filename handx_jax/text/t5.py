"""T5 in Flax: encoder (what every generator conditions on) and the small decoder used to pretrain it.

Architecture as Raffel et al. 2020 and Hugging Face's ``modeling_t5``:
- pre-norm residual blocks with T5's RMS layer norm (scale only, no mean, no bias);
- attention without the 1/sqrt(d_kv) factor (folded into the init) and with a learned
  relative-position bias: bucketed once per stack from the first layer's table, added in every layer;
- feed-forward ``relu`` (original t5) or ``gated-gelu`` (t5 v1.1 / flan, tanh-approximate GELU);
- a final layer norm per stack.

Pretrained weights are loaded intact and never re-initialised (the reference overwrote T5's linear
layers by accident, reference §3.1/§9.7; that is deliberately not ported). Parameters are plain
pytrees; ``text.hf.hf_param_names`` is the one table between Hugging Face tensor names and our tree, used by
both the loader and the exporter, so a folder we write is read back by the same code as a stock one.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.infra.errors import DataError
from handx_jax.text.tokenizer import Encoded, Tokenizer

Params = Any
FEED_FORWARD = ("relu", "gated-gelu")
SUPPORTED_MODEL_TYPES = ("t5", "mt5")


# --------------------------------------------------------------------------------------------------
# Config


@dataclass(frozen=True)
class T5Config:
    """Model dimensions with Hugging Face's field names (V, D, K = d_kv, F, H, L encoder layers)."""

    vocab_size: int
    d_model: int
    d_kv: int
    d_ff: int
    num_layers: int
    num_heads: int
    num_decoder_layers: int = 0
    relative_attention_num_buckets: int = 32
    relative_attention_max_distance: int = 128
    layer_norm_epsilon: float = 1e-6
    feed_forward_proj: str = "relu"
    tie_word_embeddings: bool = True

    def __post_init__(self):
        if self.feed_forward_proj not in FEED_FORWARD:
            raise ValueError(f"feed_forward_proj {self.feed_forward_proj!r} is not supported; "
                             f"use one of {FEED_FORWARD}")
        for f in ("vocab_size", "d_model", "d_kv", "d_ff", "num_layers", "num_heads", "relative_attention_num_buckets"):
            if int(getattr(self, f)) <= 0:
                raise ValueError(f"{f} must be positive, got {getattr(self, f)}")

    @property
    def gated(self) -> bool:
        return self.feed_forward_proj == "gated-gelu"

    @classmethod
    def from_hf(cls, doc: dict, path: str | os.PathLike | None = None) -> "T5Config":
        """Read a Hugging Face T5 ``config.json`` dict; refuse anything this encoder cannot reproduce."""
        mt = doc.get("model_type")
        if mt not in SUPPORTED_MODEL_TYPES:
            raise DataError(f"unsupported config: model_type {mt!r} (supported: {SUPPORTED_MODEL_TYPES})", path=path)
        ff = doc.get("feed_forward_proj", "relu")
        if ff not in FEED_FORWARD:
            raise DataError(f"unsupported config: feed_forward_proj {ff!r} (supported: {FEED_FORWARD})", path=path)
        kw = {}
        for f in dataclasses.fields(cls):
            if f.name in doc and doc[f.name] is not None:
                kw[f.name] = doc[f.name]
            elif f.default is dataclasses.MISSING:
                raise DataError(f"unsupported config: required key {f.name!r} is missing", path=path)
        if kw.get("num_decoder_layers") is None:
            kw["num_decoder_layers"] = 0
        try:
            return cls(**kw)
        except (TypeError, ValueError) as e:
            raise DataError(f"unsupported config: {e}", path=path) from None

    def to_hf(self, *, architecture: str = "T5EncoderModel", extra: dict | None = None) -> dict:
        doc = {"architectures": [architecture], "model_type": "t5", **dataclasses.asdict(self),
               "is_encoder_decoder": True, "pad_token_id": 0, "eos_token_id": 1, "decoder_start_token_id": 0,
               "dropout_rate": 0.0, "initializer_factor": 1.0}
        if self.num_decoder_layers == 0:
            doc["num_decoder_layers"] = self.num_layers  # HF needs a positive count; only the encoder is shipped
        if extra:
            doc.update(extra)
        return doc


# t5-base's encoder (the reference's text encoder, §3.1): what the FLOPs counts assume when no encoder
# folder is given. The one definition (families.diffusion, families.ar and diffusion.flops read it).
T5_BASE = dict(vocab_size=32128, d_model=768, d_kv=64, d_ff=3072, num_layers=12, num_heads=12)


def t5_base() -> T5Config:
    return T5Config(**T5_BASE)


def count_params(params: Params) -> int:
    return int(sum(np.prod(x.shape) for x in jax.tree.leaves(params)))


def encoder_flops(cfg: T5Config, length: int | np.ndarray) -> int | np.ndarray:
    """Analytic forward FLOPs of the encoder for one sequence of ``length`` tokens.

    Matrix products only, 2 FLOPs per multiply-add: Q/K/V/O projections, the two attention products
    (scores and weighted values), and the feed-forward (two input projections when gated). Norms,
    softmax and the embedding gather are O(L·D) and are left out, as in Kaplan et al.'s 2N count.
    """
    L, D, HK, F = np.asarray(length, np.int64), cfg.d_model, cfg.num_heads * cfg.d_kv, cfg.d_ff
    attn = 2 * L * D * 3 * HK + 2 * L * L * HK * 2 + 2 * L * HK * D
    mlp = 2 * L * D * F * (2 if cfg.gated else 1) + 2 * L * F * D
    out = cfg.num_layers * (attn + mlp)
    return int(out) if np.ndim(out) == 0 else out


# --------------------------------------------------------------------------------------------------
# Relative positions


def relative_position_bucket(relative_position: np.ndarray, *, bidirectional: bool, num_buckets: int,
                             max_distance: int) -> np.ndarray:
    """T5's bucketing of ``key - query`` offsets (Raffel et al. 2020, §2.1; Mesh TensorFlow).

    Half the buckets are exact small offsets; the rest grow logarithmically up to ``max_distance``,
    beyond which offsets share the last bucket. Encoder buckets are bidirectional (the sign takes
    half the buckets); decoder buckets see only the past. Computed on the host in float32 in the same
    operation order as the PyTorch reference, so bucket edges agree exactly.
    """
    rp = np.asarray(relative_position, np.int64)
    buckets = np.zeros_like(rp)
    if bidirectional:
        num_buckets //= 2
        buckets += (rp > 0).astype(np.int64) * num_buckets
        rp = np.abs(rp)
    else:
        rp = -np.minimum(rp, 0)
    max_exact = num_buckets // 2
    is_small = rp < max_exact
    with np.errstate(divide="ignore"):
        scaled = (np.log(rp.astype(np.float32) / np.float32(max_exact))
                  / np.float32(math.log(max_distance / max_exact)) * np.float32(num_buckets - max_exact))
    large = max_exact + np.where(is_small, 0, scaled).astype(np.int64)
    large = np.minimum(large, num_buckets - 1)
    return buckets + np.where(is_small, rp, large)


@lru_cache(maxsize=64)
def _bucket_matrix(q_len: int, k_len: int, bidirectional: bool, num_buckets: int, max_distance: int) -> np.ndarray:
    rel = np.arange(k_len)[None, :] - np.arange(q_len)[:, None]
    out = relative_position_bucket(rel, bidirectional=bidirectional, num_buckets=num_buckets,
                                   max_distance=max_distance).astype(np.int32)
    out.flags.writeable = False
    return out


# --------------------------------------------------------------------------------------------------
# Modules


def _normal(std: float):
    return nn.initializers.normal(stddev=std)


class RMSNorm(nn.Module):
    """T5 layer norm: x / sqrt(mean(x²) + eps) · scale (no centring, no bias)."""

    eps: float

    @nn.compact
    def __call__(self, x):
        scale = self.param("scale", nn.initializers.ones, (x.shape[-1],))
        var = jnp.mean(jnp.square(x.astype(jnp.float32)), axis=-1, keepdims=True)
        return scale * (x * jax.lax.rsqrt(var + self.eps))


class Attention(nn.Module):
    cfg: T5Config

    @nn.compact
    def __call__(self, x_BxQxD, kv_BxKxD, bias_BxHxQxK):
        c = self.cfg
        HK = c.num_heads * c.d_kv
        q = nn.Dense(HK, use_bias=False, kernel_init=_normal((c.d_model * c.d_kv) ** -0.5), name="q")(x_BxQxD)
        k = nn.Dense(HK, use_bias=False, kernel_init=_normal(c.d_model ** -0.5), name="k")(kv_BxKxD)
        v = nn.Dense(HK, use_bias=False, kernel_init=_normal(c.d_model ** -0.5), name="v")(kv_BxKxD)
        split = lambda t: t.reshape(*t.shape[:2], c.num_heads, c.d_kv)  # noqa: E731
        q_BxQxHxK, k_BxKxHxK, v_BxKxHxK = split(q), split(k), split(v)
        # No 1/sqrt(d_kv): T5 folds it into the initialisation of q.
        att_BxHxQxK = jnp.einsum("bqhd,bkhd->bhqk", q_BxQxHxK, k_BxKxHxK) + bias_BxHxQxK
        att_BxHxQxK = jax.nn.softmax(att_BxHxQxK.astype(jnp.float32), axis=-1)
        out_BxQxHxK = jnp.einsum("bhqk,bkhd->bqhd", att_BxHxQxK, v_BxKxHxK)
        return nn.Dense(c.d_model, use_bias=False, kernel_init=_normal(HK ** -0.5), name="o")(
            out_BxQxHxK.reshape(*x_BxQxD.shape[:2], HK))


class MLP(nn.Module):
    cfg: T5Config

    @nn.compact
    def __call__(self, x_BxLxD):
        c = self.cfg
        dense = lambda n, name, std: nn.Dense(n, use_bias=False, kernel_init=_normal(std), name=name)  # noqa: E731
        if c.gated:  # t5 v1.1 / flan: GELU(x W0) ⊙ (x W1), GELU in its tanh form ("gelu_new")
            h = jax.nn.gelu(dense(c.d_ff, "wi_0", c.d_model ** -0.5)(x_BxLxD), approximate=True)
            h = h * dense(c.d_ff, "wi_1", c.d_model ** -0.5)(x_BxLxD)
        else:  # original t5
            h = jax.nn.relu(dense(c.d_ff, "wi", c.d_model ** -0.5)(x_BxLxD))
        return dense(c.d_model, "wo", c.d_ff ** -0.5)(h)


class Block(nn.Module):
    cfg: T5Config
    cross: bool = False

    @nn.compact
    def __call__(self, x, self_bias, enc=None, cross_bias=None):
        eps = self.cfg.layer_norm_epsilon
        h = RMSNorm(eps, name="attn_norm")(x)
        x = x + Attention(self.cfg, name="attn")(h, h, self_bias)
        if self.cross:
            h = RMSNorm(eps, name="cross_norm")(x)
            x = x + Attention(self.cfg, name="cross")(h, enc, cross_bias)
        return x + MLP(self.cfg, name="mlp")(RMSNorm(eps, name="mlp_norm")(x))


NEG_INF = -1e9  # exp() of this is exactly 0 in float32: masked keys carry no weight


class Stack(nn.Module):
    """Encoder (``causal=False``) or decoder stack over already-embedded tokens."""

    cfg: T5Config
    causal: bool = False

    @nn.compact
    def __call__(self, x_BxLxD, mask_BxL, enc_BxSxD=None, enc_mask_BxS=None):
        c = self.cfg
        L = x_BxLxD.shape[1]
        n_layers = c.num_decoder_layers if self.causal else c.num_layers
        # One bias table for the whole stack (HF stores it in layer 0); bucket once, reuse in every layer.
        table = nn.Embed(c.relative_attention_num_buckets, c.num_heads, embedding_init=_normal(c.d_model ** -0.5),
                         name="rel_bias")
        buckets_LxL = _bucket_matrix(L, L, not self.causal, c.relative_attention_num_buckets,
                                     c.relative_attention_max_distance)
        pos_HxLxL = jnp.transpose(table(jnp.asarray(buckets_LxL)), (2, 0, 1))
        keep_BxLxL = jnp.broadcast_to(mask_BxL[:, None, :] > 0, (mask_BxL.shape[0], L, L))
        if self.causal:
            keep_BxLxL = keep_BxLxL & jnp.tril(jnp.ones((L, L), bool))[None]
        self_bias = pos_HxLxL[None] + jnp.where(keep_BxLxL, 0.0, NEG_INF)[:, None]
        cross_bias = None
        if self.causal:
            cross_bias = jnp.where(enc_mask_BxS[:, None, None, :] > 0, 0.0, NEG_INF)
        x = x_BxLxD
        for i in range(n_layers):
            x = Block(c, cross=self.causal, name=f"block_{i}")(x, self_bias, enc_BxSxD, cross_bias)
        return RMSNorm(c.layer_norm_epsilon, name="final_norm")(x)


class T5EncoderModel(nn.Module):
    """Token ids → last hidden states ``(B, L, D)`` (after the final layer norm), as HF's T5EncoderModel."""

    cfg: T5Config

    @nn.compact
    def __call__(self, ids_BxL, mask_BxL):
        emb = nn.Embed(self.cfg.vocab_size, self.cfg.d_model, embedding_init=_normal(1.0), name="shared")
        return Stack(self.cfg, causal=False, name="encoder")(emb(ids_BxL), mask_BxL)


class T5Model(nn.Module):
    """Encoder–decoder for span-corruption pretraining. Its ``shared`` + ``encoder`` subtrees are
    exactly a ``T5EncoderModel``'s parameters."""

    cfg: T5Config

    def setup(self):
        c = self.cfg
        self.shared = nn.Embed(c.vocab_size, c.d_model, embedding_init=_normal(1.0))
        self.encoder = Stack(c, causal=False)
        self.decoder = Stack(c, causal=True)
        if not c.tie_word_embeddings:
            self.lm_head = nn.Dense(c.vocab_size, use_bias=False, kernel_init=_normal(c.d_model ** -0.5))

    def encode(self, ids_BxS, mask_BxS):
        return self.encoder(self.shared(ids_BxS), mask_BxS)

    def __call__(self, ids_BxS, mask_BxS, dec_ids_BxT, dec_mask_BxT):
        enc_BxSxD = self.encode(ids_BxS, mask_BxS)
        h_BxTxD = self.decoder(self.shared(dec_ids_BxT), dec_mask_BxT, enc_BxSxD, mask_BxS)
        if self.cfg.tie_word_embeddings:  # original t5 rescales before the tied projection
            return self.shared.attend(h_BxTxD * self.cfg.d_model ** -0.5)
        return self.lm_head(h_BxTxD)


def encoder_params(params: Params) -> Params:
    """The frozen encoder's parameters out of a full ``T5Model`` tree."""
    return {"shared": params["shared"], "encoder": params["encoder"]}


# --------------------------------------------------------------------------------------------------
# The frozen encoder (loaded from a Hugging Face folder by handx_jax.text.hf)


def params_fingerprint(cfg: T5Config, params: Params) -> str:
    """Content hash of config and weights: identical numbers give the same key whatever the file layout."""
    h = hashlib.sha256(json.dumps(dataclasses.asdict(cfg), sort_keys=True).encode())
    leaves = {jax.tree_util.keystr(path): leaf for path, leaf in jax.tree_util.tree_flatten_with_path(params)[0]}
    for name in sorted(leaves):
        a = np.ascontiguousarray(np.asarray(leaves[name], np.float32))
        h.update(name.encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


@lru_cache(maxsize=8)
def _encoder_forward(cfg: T5Config) -> Callable:
    """One jitted forward per config, so reloading an encoder reuses its compiled shapes."""
    model = T5EncoderModel(cfg)
    # stop_gradient: downstream code may close over these outputs; the encoder stays frozen.
    return jax.jit(lambda p, ids, mask: jax.lax.stop_gradient(model.apply({"params": p}, ids, mask)))


def stored_forward(cfg: T5Config, dtype) -> Callable:
    """``f(params, ids, mask)`` → hidden states as the text cache stores them: padding zeroed, cast to
    ``dtype``. Not jitted, so callers fuse it into their own jit; the cache build and every consumer that
    re-encodes text on the fly (the evaluator) use this one function, so both see the same numbers."""
    forward, store = _encoder_forward(cfg), jnp.dtype(dtype)
    return lambda params, ids, mask: (forward(params, ids, mask) * mask[..., None]).astype(store)


@dataclass
class FrozenEncoder:
    """A loaded encoder folder: config, frozen parameters, its tokenizer, and a jitted forward."""

    cfg: T5Config
    params: Params
    tokenizer: Tokenizer
    path: Path | None = None

    def __post_init__(self):
        self._forward = _encoder_forward(self.cfg)

    @property
    def fingerprint(self) -> str:
        if not hasattr(self, "_fp"):
            self._fp = params_fingerprint(self.cfg, self.params)
        return self._fp

    def __call__(self, ids_BxL: np.ndarray, mask_BxL: np.ndarray) -> jax.Array:
        return self._forward(self.params, jnp.asarray(ids_BxL, jnp.int32), jnp.asarray(mask_BxL, jnp.int32))

    def stored_forward(self, dtype) -> Callable:
        """:func:`stored_forward` of this encoder's config."""
        return stored_forward(self.cfg, dtype)

    def encode(self, texts: Sequence[str], max_len: int | None = None) -> tuple[Encoded, np.ndarray]:
        enc = self.tokenizer.encode(texts, max_len)
        return enc, np.asarray(self(enc.ids_BxL, enc.mask_BxL))

    def flops(self, length: int | np.ndarray):
        return encoder_flops(self.cfg, length)

