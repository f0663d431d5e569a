"""A loaded evaluator (:class:`TrainedEvaluator`): embeds motion and captions into the shared latent."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import representation as rep
from handx_jax.evaluation.features import TextPolicy, joined_caption, motion_features
from handx_jax.infra.errors import DataError
from handx_jax.models.evaluator import Evaluator, EvaluatorConfig
from handx_jax.models.shape_cache import per_config
from handx_jax.text.cache import bucket_length
from handx_jax.text.t5 import stored_forward


def _pad_rows(x: np.ndarray, n: int) -> np.ndarray:
    if x.shape[0] == n:
        return x
    pad = np.zeros((n - x.shape[0],) + x.shape[1:], x.dtype)
    return np.concatenate([x, pad])


def _chunk_size(n: int, cap: int) -> int:
    """A power of two ≥ n, capped: few distinct batch shapes → few compiles."""
    return int(min(cap, 1 << max(int(np.ceil(np.log2(max(n, 1)))), 3)))


@dataclass
class TrainedEvaluator:
    """A loaded evaluator: embeds motion and captions into the shared latent (μ, dimension ``latent``)."""

    cfg: EvaluatorConfig
    params: Any
    stats: rep.NormStats
    encoder: Any  # handx_jax.text.t5.FrozenEncoder
    policy: TextPolicy
    meta: dict = field(default_factory=dict)
    root: Path | None = None
    batch_size: int = 256

    @cached_property
    def _model(self) -> Evaluator:
        return Evaluator(self.cfg)

    @cached_property
    def _motion_fn(self) -> Callable:
        return _motion_program(self.cfg)

    @cached_property
    def _text_fn(self) -> Callable:
        return _text_program(self.cfg, self.encoder, self.policy.cache_dtype)

    @cached_property
    def fingerprint(self) -> str:
        """Hash of what the embeddings depend on besides the encoder: config, parameters, motion statistics.
        Keys the reference-embedding cache (a retrained evaluator never reuses old embeddings); computed
        once, so replace the evaluator object rather than its ``params`` after first use."""
        from flax import serialization

        h = hashlib.sha256(json.dumps(dataclasses.asdict(self.cfg), sort_keys=True).encode())
        h.update(serialization.to_bytes(jax.device_get(self.params)))
        for a in (self.stats.mean, self.stats.std, np.float32(self.stats.eps)):
            h.update(np.ascontiguousarray(a, np.float32).tobytes())
        return h.hexdigest()[:16]

    @property
    def dataset_fingerprint(self) -> str | None:
        return self.meta.get("dataset", {}).get("fingerprint")

    def check_dataset(self, ds) -> None:
        """Refuse a reference dataset other than the one this evaluator was trained on (:func:`check_trained_dataset`)."""
        check_trained_dataset(self.meta, ds)

    def embed_motion(self, joints_NxTx2x21x3: np.ndarray) -> np.ndarray:
        """(N, latent) μ-embeddings of joint sequences in metres."""
        joints = np.asarray(joints_NxTx2x21x3, np.float32)
        n = joints.shape[0]
        out = np.zeros((n, self.cfg.latent), np.float32)
        B = _chunk_size(n, self.batch_size)
        for s in range(0, n, B):
            x = motion_features(joints[s:s + B], self.stats, self.cfg.motion_input)
            k = x.shape[0]
            out[s:s + k] = np.asarray(self._motion_fn(self.params, jnp.asarray(_pad_rows(x, B))))[:k]
        return out

    def embed_joined(self, texts: Sequence[str]) -> np.ndarray:
        """(N, latent) μ-embeddings of joined captions, encoded with the frozen T5 on the fly."""
        tok = self.encoder.tokenizer
        L = self.policy.max_len
        seqs = [tok.encode_one(t) for t in texts]
        seqs = [s if len(s) <= L else s[:L - 1] + [1] for s in seqs]
        lengths = np.array([len(s) for s in seqs], np.int64)
        n = len(seqs)
        out = np.zeros((n, self.cfg.latent), np.float32)
        B = _chunk_size(n, self.batch_size)
        order = np.argsort(-lengths, kind="stable")  # longest first: each chunk padded to its own bucket
        for s in range(0, n, B):
            sel = order[s:s + B]
            Lb = bucket_length(int(lengths[sel].max()), 32, L)
            ids = np.zeros((B, Lb), np.int32)
            mask = np.zeros((B, Lb), np.int32)
            ids[len(sel):, 0], mask[len(sel):, 0] = 1, 1  # filler rows: a lone eos
            for r, k in enumerate(sel):
                ids[r, :lengths[k]], mask[r, :lengths[k]] = seqs[k], 1
            e = self._text_fn(self.params, self.encoder.params, jnp.asarray(ids), jnp.asarray(mask))
            out[sel] = np.asarray(e)[:len(sel)]
        return out

    def embed_text(self, left: Sequence[str], right: Sequence[str], interaction: Sequence[str]) -> np.ndarray:
        """(N, latent) μ-embeddings of N (left, right, interaction) prompts."""
        if not len(left) == len(right) == len(interaction):
            raise ValueError(f"unequal prompt lists: {len(left)} left, {len(right)} right, "
                             f"{len(interaction)} interaction")
        return self.embed_joined([joined_caption(a, b, c, self.policy.caption)
                                  for a, b, c in zip(left, right, interaction)])

    def captions(self, ds, clips: np.ndarray) -> tuple[list[str], list[str], list[str]]:
        """The reference prompts of ``clips`` at the policy's evaluation level."""
        lv = self.policy.eval_level
        texts = [ds.texts[int(c)] for c in clips]
        return ([t["left"][lv] for t in texts], [t["right"][lv] for t in texts],
                [t["interaction"][lv] for t in texts])




# One jitted program per evaluator config (and encoder config, cache dtype) in a process, as the T5 encoder has
# (text.t5._encoder_forward): every evaluator loaded with it (a reload, a copy, other weights of the same size,
# each evaluation of a sweep's process) reuses its traced and compiled shapes instead of tracing, lowering and
# compiling its own (~0.3-0.5 CPU-s per function and batch shape even from the persistent cache).
@per_config
def _motion_program(cfg: EvaluatorConfig) -> Callable:
    model = Evaluator(cfg)
    return jax.jit(lambda p, x: model.apply(p, x, method=Evaluator.encode_motion)[0])


def _text_program(cfg: EvaluatorConfig, encoder, cache_dtype) -> Callable:
    """The jitted caption encoder: the frozen T5 as the text cache stores its output (cache_dtype, padding
    zeroed; training read that cache), then the evaluator's text branch. Keyed by the configs alone: the
    encoder's stored forward is a function of its config (text.t5.stored_forward), its weights an argument."""
    return _text_program_of(cfg, encoder.cfg, jnp.dtype(cache_dtype).name)


@lru_cache(maxsize=16)
def _text_program_of(cfg: EvaluatorConfig, enc_cfg, cache_dtype: str) -> Callable:
    model, stored = Evaluator(cfg), stored_forward(enc_cfg, cache_dtype)

    def f(p, enc_params, ids, mask):
        h = stored(enc_params, ids, mask).astype(jnp.float32)
        return model.apply(p, h, mask.astype(bool), method=Evaluator.encode_text)[0]

    return jax.jit(f)


def _init_params(cfg: EvaluatorConfig, text_len: int, rng: jax.Array | None = None):
    model = Evaluator(cfg)
    rng = jax.random.PRNGKey(0) if rng is None else rng
    x = jnp.zeros((1, cfg.frames, cfg.motion_dim))
    t = jnp.zeros((1, min(text_len, 8), cfg.text_dim))
    m = jnp.ones((1, min(text_len, 8)), bool)
    return jax.jit(lambda r: model.init(r, x, t, m))(rng)


def param_shapes(cfg: EvaluatorConfig, text_len: int):
    """The parameter tree of :func:`_init_params` as shapes and dtypes only (``jax.eval_shape``): the
    template a saved evaluator is read into. Tracing costs ~0.3 CPU-s where compiling the init costs ~6
    in a fresh process, paid by every `handx eval run` and sweep evaluate stage."""
    return jax.eval_shape(lambda: _init_params(cfg, text_len))


def check_trained_dataset(meta: dict, ds) -> None:
    """Refuse a reference dataset other than the one the evaluator of ``meta`` (its ``evaluator.json``) was
    trained on; a rebuild of its recipe that differs only by float rounding is accepted and reported
    (data.dataset.check_compatible). From the JSON alone, so commands check it before loading any weights."""
    import sys

    from handx_jax.dataset.format import check_compatible

    c = check_compatible(meta.get("dataset"), ds, what="this evaluator", made="trained on",
                         fix=f"evaluate against the dataset the evaluator was trained on "
                             f"({(meta.get('dataset') or {}).get('path')}), or train a new evaluator with "
                             f"`handx train evaluator --data {ds.root}`")
    if c.message:
        print(c.message, file=sys.stderr)
