"""Offline T5 pretraining on a dataset's captions with span corruption; exports the frozen encoder.

Used when no pretrained T5 is on disk. Objective (Raffel et al. 2020, §3.1.4 and §3.3.4): drop 15% of
a caption's tokens in spans of mean length 3, replace each span by one sentinel in the encoder input,
and train the decoder to emit ``sentinel₀ span₀ sentinel₁ span₁ … </s>``. Recipe of T5 v1.1: gated-GELU
feed-forward, untied output head, no dropout in pretraining.

The run trains through the one training loop (``handx_jax.train``): the folder holds its
``config.json``, ``metrics.jsonl`` (training rows every ``log_every`` steps; ``eval_loss`` rows at step
0, every ``eval_every`` steps and at the end) and ``checkpoints/`` (orbax), and, when training ends,
``encoder/``: config.json + model.safetensors + spiece.model in Hugging Face's layout, so
``text.hf.load_hf_t5_encoder`` serves stock and home-made encoders alike. Batches and corruption noise
are pure functions of (seed, step) (the loop's ``get_step_batch``), so a resumed run reproduces an
uninterrupted one exactly. ``PretrainConfig`` is a config of ``handx_jax.config`` (dotted overrides,
``validate``).
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from handx_jax.config import ConfigError, get_preset
from handx_jax.infra.atomic import atomic_write_json
from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_jsonl
from handx_jax.text import tokenizer as tk
from handx_jax.text.hf import save_hf_t5_encoder
from handx_jax.text.t5 import T5Config, T5Model, count_params, encoder_params

# Named size ladder: encoder (what downstream models see) + a deliberately small decoder.
PRESETS: dict[str, dict] = {
    "tiny": dict(d_model=64, d_kv=16, num_heads=4, d_ff=128, num_layers=2, num_decoder_layers=1),
    "small": dict(d_model=256, d_kv=32, num_heads=8, d_ff=512, num_layers=4, num_decoder_layers=2),
    "base": dict(d_model=512, d_kv=64, num_heads=8, d_ff=1024, num_layers=8, num_decoder_layers=2),
}
# Per-preset training defaults: (steps, batch size, peak learning rate).
PRESET_TRAINING = {"tiny": (2000, 64, 2e-3), "small": (6000, 64, 1e-3), "base": (12000, 64, 5e-4)}


def model_config(preset: str, vocab_size: int) -> T5Config:
    return T5Config(vocab_size=vocab_size, feed_forward_proj="gated-gelu", tie_word_embeddings=False,
                    **get_preset(PRESETS, preset))


@dataclass(frozen=True)
class PretrainConfig:
    preset: str = "tiny"
    steps: int = 0  # 0: the preset's default
    batch_size: int = 0  # 0: the preset's default
    lr: float = 0.0  # 0: the preset's default
    warmup_frac: float = 0.05
    weight_decay: float = 0.01
    grad_clip: float = 1.0
    max_len: int = 128  # encoder input tokens, eos included
    noise_density: float = 0.15
    mean_noise_span_length: float = 3.0
    seed: int = 0
    log_every: int = 10
    ckpt_every: int = 500
    eval_every: int = 500
    eval_size: int = 256

    def validate(self) -> None:
        get_preset(PRESET_TRAINING, self.preset)
        if not 0 < self.noise_density < 1:
            raise ConfigError(f"noise_density must be in (0, 1), got {self.noise_density}")
        if self.max_len < 4:
            raise ConfigError(f"max_len must be >= 4, got {self.max_len}")

    def resolved(self) -> "PretrainConfig":
        self.validate()
        steps, bs, lr = PRESET_TRAINING[self.preset]
        return dataclasses.replace(self, steps=self.steps or steps, batch_size=self.batch_size or bs,
                                   lr=self.lr or lr)


# --------------------------------------------------------------------------------------------------
# Span corruption (T5's random_spans_noise_mask, with host-side numpy randomness)


def _spans(n: int, density: float, mean_span: float, max_spans: int) -> tuple[int, int]:
    """(noise tokens, spans) for a sequence of n tokens."""
    num_noise = min(max(int(round(n * density)), 1), max(n - 1, 1))
    num_spans = max(int(round(num_noise / mean_span)), 1)
    return num_noise, max(1, min(num_spans, n - num_noise if n > num_noise else 1, max_spans))


def _segment(num_items: int, num_segments: int, rng: np.random.Generator) -> np.ndarray:
    """A uniformly random split of num_items into num_segments positive lengths (0s if no items)."""
    if num_items == 0:
        return np.zeros(num_segments, np.int64)
    cuts = np.sort(rng.choice(num_items - 1, num_segments - 1, replace=False)) + 1 if num_segments > 1 else []
    return np.diff(np.concatenate([[0], cuts, [num_items]])).astype(np.int64)


def span_corrupt(tokens: np.ndarray, sentinels: Sequence[int], rng: np.random.Generator, *,
                 density: float = 0.15, mean_span: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """One caption (ids without eos) → (encoder input, decoder target), both ending in eos.

    Spans alternate non-noise/noise starting with non-noise, as in T5; span k becomes ``sentinels[k]``.
    """
    n = len(tokens)
    num_noise, num_spans = _spans(n, density, mean_span, len(sentinels))
    noise_len = _segment(num_noise, num_spans, rng)
    keep_len = _segment(n - num_noise, num_spans, rng)
    inputs, targets, pos = [], [], 0
    for k in range(num_spans):
        inputs += tokens[pos:pos + keep_len[k]].tolist()
        pos += keep_len[k]
        inputs.append(sentinels[k])
        targets.append(sentinels[k])
        targets += tokens[pos:pos + noise_len[k]].tolist()
        pos += noise_len[k]
    return np.asarray(inputs + [tk.EOS_ID], np.int32), np.asarray(targets + [tk.EOS_ID], np.int32)


def target_length(max_tokens: int, density: float, mean_span: float, max_spans: int) -> int:
    """Longest decoder target any caption of up to ``max_tokens`` tokens can produce."""
    return max(sum(_spans(n, density, mean_span, max_spans)) + 1 for n in range(1, max_tokens + 1))


@dataclass(frozen=True)
class Batch:
    ids_BxS: np.ndarray
    mask_BxS: np.ndarray
    dec_ids_BxT: np.ndarray  # targets shifted right behind pad (T5's decoder start token)
    targets_BxT: np.ndarray
    weights_BxT: np.ndarray


def make_batch(seqs: Sequence[np.ndarray], sentinels: Sequence[int], rng: np.random.Generator, S: int, T: int,
               density: float, mean_span: float) -> Batch:
    B = len(seqs)
    ids, targ = np.zeros((B, S), np.int32), np.zeros((B, T), np.int32)
    for i, s in enumerate(seqs):
        inp, tgt = span_corrupt(s, sentinels, rng, density=density, mean_span=mean_span)
        ids[i, :len(inp)], targ[i, :len(tgt)] = inp, tgt
    mask = (ids != tk.PAD_ID).astype(np.int32)
    weights = (targ != tk.PAD_ID).astype(np.int32)
    dec = np.concatenate([np.zeros((B, 1), np.int32), targ[:, :-1]], axis=1)
    return Batch(ids, mask, dec, targ, weights)


class CaptionStream:
    """Deterministic batches: the batch of step s depends only on (seed, s)."""

    def __init__(self, seqs: list[np.ndarray], sentinels: Sequence[int], cfg: PretrainConfig):
        self.seqs, self.sentinels, self.cfg = seqs, list(sentinels), cfg
        self.S = cfg.max_len
        self.T = target_length(cfg.max_len - 1, cfg.noise_density, cfg.mean_noise_span_length, len(sentinels))
        self._perm: dict[int, np.ndarray] = {}

    def _perm_for(self, epoch: int) -> np.ndarray:
        if epoch not in self._perm:
            self._perm = {epoch: np.random.default_rng([self.cfg.seed, 0, epoch]).permutation(len(self.seqs))}
        return self._perm[epoch]

    def batch(self, step: int) -> Batch:
        B, N = self.cfg.batch_size, len(self.seqs)
        pos = step * B + np.arange(B)
        idx = [self._perm_for(int(p // N))[int(p % N)] for p in pos]
        rng = np.random.default_rng([self.cfg.seed, 1, step])
        return make_batch([self.seqs[i] for i in idx], self.sentinels, rng, self.S, self.T,
                          self.cfg.noise_density, self.cfg.mean_noise_span_length)

    def fixed(self, seqs: list[np.ndarray], seed: int) -> list[Batch]:
        """Evaluation batches with fixed corruption, all of one shape (the last is padded with
        zero-weight rows, so a single compiled eval step serves them all)."""
        rng = np.random.default_rng([seed, 2])
        B = self.cfg.batch_size
        out = []
        for i in range(0, len(seqs), B):
            b = make_batch(seqs[i:i + B], self.sentinels, rng, self.S, self.T, self.cfg.noise_density,
                           self.cfg.mean_noise_span_length)
            if len(b.ids_BxS) < B:
                pad = lambda a: np.concatenate([a, np.zeros((B - len(a),) + a.shape[1:], a.dtype)])  # noqa: E731
                b = Batch(*(pad(getattr(b, f.name)) for f in dataclasses.fields(Batch)))
                b.mask_BxS[len(seqs) - i:, 0] = 1  # keep padded encoder rows non-empty
            out.append(b)
        return out


# --------------------------------------------------------------------------------------------------
# Model, loss, optimiser


def loss_fn(model: T5Model, params, b: Batch | dict) -> tuple[jax.Array, jax.Array]:
    """Mean cross-entropy per target token, and the number of target tokens."""
    g = (lambda k: b[k]) if isinstance(b, dict) else (lambda k: getattr(b, k))  # noqa: E731
    logits_BxTxV = model.apply({"params": params}, g("ids_BxS"), g("mask_BxS"), g("dec_ids_BxT"), g("weights_BxT"))
    ce_BxT = optax.softmax_cross_entropy_with_integer_labels(logits_BxTxV.astype(jnp.float32), g("targets_BxT"))
    w = g("weights_BxT").astype(jnp.float32)
    n = jnp.maximum(w.sum(), 1.0)
    return (ce_BxT * w).sum() / n, n


def make_schedule(cfg: PretrainConfig) -> optax.Schedule:
    """Linear warm-up, then cosine decay to a tenth of the peak."""
    warmup = max(1, int(cfg.warmup_frac * cfg.steps))
    return optax.warmup_cosine_decay_schedule(0.0, cfg.lr, warmup, max(cfg.steps, warmup + 1), end_value=cfg.lr * 0.1)


def make_optimizer(cfg: PretrainConfig) -> optax.GradientTransformation:
    """AdamW with weight decay on matrices only (not embeddings, norms or position biases)."""
    sched = make_schedule(cfg)
    decay_mask = lambda p: jax.tree_util.tree_map_with_path(  # noqa: E731
        lambda path, _: jax.tree_util.keystr(path).endswith("['kernel']"), p)
    return optax.chain(optax.clip_by_global_norm(cfg.grad_clip),
                       optax.adamw(sched, b1=0.9, b2=0.999, eps=1e-8, weight_decay=cfg.weight_decay, mask=decay_mask))


def batch_dict(b: Batch) -> dict[str, np.ndarray]:
    return dataclasses.asdict(b)


# --------------------------------------------------------------------------------------------------
# The run


def param_counts(cfg: T5Config, params) -> dict[str, int]:
    emb = int(np.prod(params["shared"]["embedding"].shape))
    enc = count_params(params["encoder"])
    return {"all": count_params(params), "embedding": emb, "encoder_non_embedding": enc,
            "encoder_total": enc + emb, "decoder": count_params(params["decoder"]) +
            (count_params(params["lm_head"]) if "lm_head" in params else 0)}


def _captions(ds, split: str) -> list[str]:
    return list(dict.fromkeys(tk.dataset_captions(ds, [split])))  # unique, first-appearance order


TRAINABLE = "t5"  # config.json's "trainable": `handx train t5` (families.TRAINABLES); no model family


def _run_identity(cfg: PretrainConfig, mcfg: T5Config, ds_fp: str, tok: tk.Tokenizer) -> dict:
    """What a resumed run must share with the original (paths may differ; content may not)."""
    return {"trainable": TRAINABLE, "pretrain": dataclasses.asdict(cfg), "model": dataclasses.asdict(mcfg),
            "dataset_fingerprint": ds_fp, "tokenizer_fingerprint": tok.fingerprint}


def pretrain(data_dir: str | os.PathLike, out: str | os.PathLike, cfg: PretrainConfig,
             log: Callable[[str], None] = print, tokenizer: tk.Tokenizer | None = None,
             stop_at_step: int | None = None) -> dict | None:
    """Train (or resume) a run in ``out``; return the summary also written to ``out/pretrain.json``.

    ``stop_at_step`` ends this invocation early with a checkpoint at that step (a pre-emptible job's
    time slice) and returns None; rerunning the same call continues from there. The encoder is
    exported once all ``cfg.steps`` are done.
    """
    from handx_jax.dataset.format import Dataset
    from handx_jax.runlog import trainable_renamed
    from handx_jax.train import TrainConfig, TrainSpec, check_resume, train

    t_start = time.perf_counter()
    cfg = cfg.resolved()
    data_dir, out = Path(data_dir), Path(out).absolute()
    ds = Dataset.open(data_dir)
    if tokenizer is None:
        if (tk.tokenizer_dir(data_dir) / tk.MODEL_FILENAME).exists():
            tokenizer = tk.load_for_dataset(data_dir)
        else:
            log(f"no tokenizer beside {data_dir}; training one on its train captions")
            tokenizer = tk.train_for_dataset(data_dir)
    mcfg = model_config(cfg.preset, tokenizer.vocab_size)
    identity = _run_identity(cfg, mcfg, ds.fingerprint, tokenizer)

    train_caps = _captions(ds, "train")
    if not train_caps:
        raise DataError("the train split has no captions to pretrain on", path=data_dir)
    eval_caps = _captions(ds, "val") or train_caps
    eval_caps = [eval_caps[i] for i in np.random.default_rng([cfg.seed, 3]).permutation(len(eval_caps))[:cfg.eval_size]]
    # Captions are cut to max_len - 1 tokens so that the corrupted input plus eos fits in max_len.
    train_full = [tokenizer.encode_one(c, add_eos=False) for c in train_caps]
    n_trunc = sum(len(t) > cfg.max_len - 1 for t in train_full)
    train_seqs = [np.asarray(t[:cfg.max_len - 1], np.int32) for t in train_full]
    eval_seqs = [np.asarray(tokenizer.encode_one(c, add_eos=False)[:cfg.max_len - 1], np.int32) for c in eval_caps]
    sentinels = [tokenizer.sentinel_id(i) for i in range(tokenizer.num_sentinels)]
    stream = CaptionStream(train_seqs, sentinels, cfg)
    eval_batches = [batch_dict(b) for b in stream.fixed(eval_seqs, cfg.seed)]

    # The loop's view of this run: T5 v1.1's optimiser recipe (make_optimizer), no EMA, float32.
    tcfg = TrainConfig(steps=cfg.steps, batch_size=cfg.batch_size, seed=cfg.seed, log_every=cfg.log_every,
                       ckpt_every=cfg.ckpt_every, keep_checkpoints=2, eval_every=cfg.eval_every, wandb="disabled")
    model = T5Model(mcfg)
    S, T = stream.S, stream.T

    def init(_rng):
        # Keyed by the config seed alone (not the loop's key), as before this run used the shared loop.
        ids, dec = jnp.zeros((1, S), jnp.int32), jnp.zeros((1, T), jnp.int32)
        return model.init(jax.random.key(cfg.seed), ids, jnp.ones_like(ids), dec, jnp.ones_like(dec))["params"]

    def loss(params, batch, _rng, _train):
        l, n = loss_fn(model, params, batch)
        return l, {"target_tokens": n}

    eval_step = jax.jit(lambda p, b: loss_fn(model, p, b))

    def evaluate(params, _ema, step) -> dict:
        tot = n = 0.0
        for b in eval_batches:
            l, k = eval_step(params, b)
            tot, n = tot + float(l) * float(k), n + float(k)
        return {"eval_loss": tot / max(n, 1.0)}

    shapes = jax.eval_shape(init, None)
    counts = param_counts(mcfg, shapes)
    config = {**identity, "paths": {"data": str(data_dir), "tokenizer": str(tokenizer.path)},
              "n_params": counts, "train_captions": len(train_seqs), "eval_captions": len(eval_seqs),
              "truncated_train_captions": int(n_trunc), "input_len": S, "target_len": T}
    resume_keys = [*identity, "train"]
    upgrade = trainable_renamed("t5-pretrain", TRAINABLE)  # runs written before issue 42 resume too
    check_resume(out, {**config, "train": dataclasses.asdict(tcfg)}, resume_keys, upgrade)
    latest = _latest_checkpoint(out)
    if latest is None:
        log(f"pretrain {cfg.preset}: {counts['encoder_total']:,} encoder params ({counts['all']:,} with decoder), "
            f"{len(train_seqs)} unique train captions, {cfg.steps} steps × batch {cfg.batch_size}")
    else:
        log(f"resuming {out} from step {latest}")

    def on_log(row):
        if "eval_loss" in row:
            log(f"step {row['step']}: eval span-corruption loss {row['eval_loss']:.4f}")

    spec = TrainSpec(init=init, loss=loss, cfg=tcfg, config=config,
                     get_step_batch=lambda step: batch_dict(stream.batch(step)), evaluate=evaluate,
                     optimizer=(make_optimizer(cfg), make_schedule(cfg)), resume_keys=resume_keys,
                     upgrade_config=upgrade)
    res = train(out, spec, on_log=on_log, stop_at=stop_at_step, save_at_stop=True)
    step = int(res["step"])
    if step < cfg.steps:
        log(f"stopped at step {step} of {cfg.steps} after {time.perf_counter() - t_start:.1f} s; rerun to resume")
        return None

    enc_dir = out / "encoder"
    save_hf_t5_encoder(enc_dir, mcfg, jax.device_get(encoder_params(res["params"])), tokenizer, overwrite=True,
                       extra_config={"handx": {"source": "handx text pretrain", "preset": cfg.preset,
                                               "steps": cfg.steps, "dataset_fingerprint": ds.fingerprint}})
    rows = read_jsonl(out / "metrics.jsonl", strict=False)
    evals = [r for r in rows if "eval_loss" in r]
    trains = [r for r in rows if "loss" in r]
    summary = {"preset": cfg.preset, "steps": cfg.steps, "batch_size": cfg.batch_size,
               "eval_loss_start": evals[0]["eval_loss"], "eval_loss_end": evals[-1]["eval_loss"],
               "train_loss_first": trains[0]["loss"] if trains else None,
               "train_loss_last": trains[-1]["loss"] if trains else None,
               "wall_s": time.perf_counter() - t_start, "resumed_from": latest, "encoder": str(enc_dir)}
    atomic_write_json(out / "pretrain.json", summary)
    log(f"pretrain done: eval span-corruption loss {summary['eval_loss_start']:.4f} → {summary['eval_loss_end']:.4f}; "
        f"train loss {summary['train_loss_first']} → {summary['train_loss_last']}; "
        f"wall {summary['wall_s']:.1f} s; encoder in {enc_dir}")
    return summary


def _latest_checkpoint(out: Path) -> int | None:
    steps = [int(p.name) for p in (out / "checkpoints").glob("[0-9]*") if p.name.isdigit()] \
        if (out / "checkpoints").is_dir() else []
    return max(steps) if steps else None
