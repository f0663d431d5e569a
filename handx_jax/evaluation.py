"""Evaluator training, the versioned evaluator checkpoint, and evaluation of generated motion.

Pipeline (paper E.2; reference §5.1–§5.4):

- **Motion side**: joints ``(N, 60, 2, 21, 3)`` → :func:`representation.to_evaluator` (per-frame
  right-wrist centring, §5.3) → z-scored with the training dataset's ``evaluator_mean/std`` (the
  same preprocessing in training and evaluation; the reference mixes two, §9.17).
- **Text side**: ``<extra_id_0> L <extra_id_1> R <extra_id_2> I <extra_id_3>`` per (clip, level),
  encoded by the frozen T5 (read from the joined text cache in training, encoded on the fly at
  evaluation and rounded to the cache dtype so both paths give the same numbers).
- **Training items** are (clip, level) pairs: each sample draws its level at random from the policy's
  ``train_levels``. The reference draws the three fields independently (§1.2); we keep the three fields
  of one level together because they are encoded as one sequence (one cache row per (clip, level)).
  Levels are a pure function of the batch's clip indices and the seed, so a resumed run sees exactly
  the same (clip, level) items.
- **Evaluation** scores every motion against the reference caption of its source clip at the
  policy's ``eval_level`` ("predictions are scored against the same caption as their GT", §5.3).

Checkpoint folder ``E`` (format ``handx-jax-evaluator`` v1), complete once ``evaluator.json`` exists:

    evaluator.json   format, version, evaluator config, text policy, dataset fingerprint + path,
                     encoder folder + fingerprint, tokenizer fingerprint, text-cache fingerprint/dtype/Lmax,
                     training summary (steps, batch, lr, wall time, final losses)
    params.msgpack   Flax-serialised evaluator parameters (final step)
    norm_stats.npz   evaluator_mean/std/eps used to normalise motion features
    eval.json        the Ground Truth row on the training dataset's test split (schema metric names)
    config.json, metrics.jsonl, checkpoints/   the training run (handx_jax.train; resumable)
    reference_cache/ text and GT-motion embeddings of evaluated reference clips, one file per key
                     (:func:`reference_embeddings`; safe to delete, rebuilt on the next evaluation)

:func:`load_evaluator` refuses a folder of another format/version, an encoder whose weights changed,
and (through :meth:`TrainedEvaluator.check_dataset`) a reference dataset other than the one trained on.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import time
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import representation as rep
from handx_jax.io import (DataError, atomic_write_bytes, atomic_write_json, read_format_meta, read_params_msgpack,
                          write_params_msgpack)
from handx_jax.metrics import MetricConfig, replicate_embedding_metrics, replicate_motion_metrics
from handx_jax.models.evaluator import PRESETS, Evaluator, EvaluatorConfig, evaluator_loss
from handx_jax.text.cache import bucket_length

FORMAT, FORMAT_VERSION = "handx-jax-evaluator", 1
META_FILE, PARAMS_FILE, STATS_FILE, EVAL_FILE = "evaluator.json", "params.msgpack", "norm_stats.npz", "eval.json"
JOINED = "joined"


@dataclass(frozen=True)
class TextPolicy:
    """Which captions the evaluator sees. ``train_levels=None`` means every level of the dataset.

    ``max_len`` truncates the joined caption (first max_len−1 tokens + eos, as the cache and Hugging
    Face do); the truncated fraction is recorded at training time. ``eval_level`` indexes the level
    lists (negative from the end, −1 = most detailed, 0 = most concise).
    """

    max_len: int = 256
    train_levels: tuple[int, ...] | None = None
    eval_level: int = 0
    cache_dtype: str = "float16"


# ------------------------------------------------------------------------------------------------
# Features


def motion_features(joints_NxTx2x21x3: np.ndarray, stats: rep.NormStats, kind: str = "positions") -> np.ndarray:
    """Evaluator input ``(N, T, F)`` float32, then z-scored. ``kind`` "positions": per-frame right-wrist
    centring (§5.3, F = 126); "hand_frames": those plus derived features (F = 307)."""
    fn, _ = rep.EVALUATOR_INPUTS[kind]
    x = fn(np.asarray(joints_NxTx2x21x3, np.float32))
    return np.asarray(stats.normalize(x), np.float32)


STATS_CLIPS = 4096  # clips (evenly spaced over the train split) behind the "hand_frames" statistics


def evaluator_stats(ds, kind: str = "positions", clips: np.ndarray | None = None) -> rep.NormStats:
    """Normalisation of the evaluator input. "positions": the dataset's ``evaluator_mean/std`` (train
    split, written at build time). Other inputs: mean/std over frames of up to :data:`STATS_CLIPS`
    evenly spaced ``clips`` (default the train split); constant features (e.g. the middle MCP's
    local y, z, zero by construction) get std 1. Stored with the evaluator, so evaluation reuses them."""
    if kind == "positions":
        return rep.NormStats.from_npz_dict(ds.stats, "evaluator")
    clips = np.sort(np.asarray(ds.split("train") if clips is None else clips, np.int64))
    if len(clips) == 0:
        raise DataError("no clips to compute evaluator input statistics from", path=ds.root)
    pick = clips[np.unique(np.linspace(0, len(clips) - 1, min(len(clips), STATS_CLIPS)).round().astype(np.int64))]
    fn, _ = rep.EVALUATOR_INPUTS[kind]
    # Streamed 256 clips at a time (4,096 clips of 307 float64 features would be 600 MB at once), with
    # the positions preset's std floor.
    chunks = (fn(np.asarray(ds.motion[pick[s:s + 256]], np.float32)) for s in range(0, len(pick), 256))
    return rep.compute_norm_stats(chunks, axis=(0, 1), min_std=rep.NORM_PRESETS["evaluator"].min_std)


def joined_caption(left: str, right: str, interaction: str) -> str:
    """The evaluator's caption (reference §5.3, with real sentinels; identical to the joined cache's)."""
    from handx_jax.text.tokenizer import join_fields, sentinel

    return f"{join_fields(left, right, interaction)} {sentinel(3)}"


def _level_index(level: int, levels: int) -> int:
    if not -levels <= level < levels:
        raise ValueError(f"level {level} out of range for {levels} levels")
    return level % levels


class TrainingData:
    """(clip, level) items of one split: motion from the dataset memmap, text from the joined cache."""

    def __init__(self, ds, cache, stats: rep.NormStats, clips: np.ndarray, levels: Sequence[int], seed: int,
                 text_bucket: int = 16, motion_input: str = "positions"):
        self.ds, self.cache, self.stats = ds, cache, stats
        self.motion_input = motion_input
        self.clips = np.asarray(clips, np.int64)
        self.levels = np.asarray(levels, np.int64)
        self.seed = int(seed)
        self.text_bucket = int(text_bucket)

    def __len__(self) -> int:
        return len(self.clips)

    def item_levels(self, idx: np.ndarray) -> np.ndarray:
        """One random level per sample, a pure function of (seed, the batch's indices): exact resume."""
        rng = np.random.default_rng([self.seed, 0x1E7, *np.asarray(idx, np.int64).tolist()])
        return self.levels[rng.integers(0, len(self.levels), len(idx))]

    def batch(self, idx: np.ndarray, levels: np.ndarray | None = None) -> dict[str, np.ndarray]:
        clips = self.clips[np.asarray(idx)]
        levels = self.item_levels(idx) if levels is None else np.asarray(levels)
        order = np.argsort(clips, kind="stable")  # sorted memmap reads
        joints = np.empty((len(clips),) + self.ds.motion.shape[1:], np.float32)
        joints[order] = self.ds.motion[clips[order]]
        h, m = self.cache.lookup(clips, JOINED, levels)
        # Trim the text to the batch's longest caption, rounded up to a multiple of ``text_bucket`` tokens:
        # concise levels then cost a fraction of Lmax, and at most Lmax/bucket step shapes are compiled.
        # Masking makes the loss independent of the padding; on an accelerator, where each new shape
        # is a compile of the whole step, pass a bucket ≥ Lmax (one shape).
        Lb = bucket_length(int(m.sum(1).max()), max(self.text_bucket, 1), m.shape[1])
        return {"motion": motion_features(joints, self.stats, self.motion_input), "text": np.asarray(h[:, :Lb], np.float32),
                "text_mask": np.asarray(m[:, :Lb], bool)}


# ------------------------------------------------------------------------------------------------
# The trained evaluator


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
        model = self._model
        return jax.jit(lambda p, x: model.apply(p, x, method=Evaluator.encode_motion)[0])

    @cached_property
    def _text_fn(self) -> Callable:
        # Training read the cache (cache_dtype, padding zeroed): encode exactly as the cache build does.
        model, stored = self._model, self.encoder.stored_forward(self.policy.cache_dtype)

        def f(p, enc_params, ids, mask):
            h = stored(enc_params, ids, mask).astype(jnp.float32)
            return model.apply(p, h, mask.astype(bool), method=Evaluator.encode_text)[0]

        return jax.jit(f)

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
        """Refuse a reference dataset other than the one this evaluator was trained on; a rebuild of its
        recipe that differs only by float rounding is accepted and reported (data.dataset.check_compatible)."""
        import sys

        from handx_jax.data.dataset import check_compatible

        c = check_compatible(self.meta.get("dataset"), ds, what="this evaluator",
                             fix=f"evaluate against the dataset the evaluator was trained on "
                                 f"({self.meta.get('dataset', {}).get('path')}), or train a new evaluator with "
                                 f"`handx eval train-evaluator --data {ds.root}`")
        if c.message:
            print(c.message, file=sys.stderr)

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
        return self.embed_joined([joined_caption(a, b, c) for a, b, c in zip(left, right, interaction)])

    def captions(self, ds, clips: np.ndarray) -> tuple[list[str], list[str], list[str]]:
        """The reference prompts of ``clips`` at the policy's evaluation level."""
        lv = self.policy.eval_level
        texts = [ds.texts[int(c)] for c in clips]
        return ([t["left"][lv] for t in texts], [t["right"][lv] for t in texts],
                [t["interaction"][lv] for t in texts])


# ------------------------------------------------------------------------------------------------
# Checkpoint folder


def _policy_from_json(d: Mapping) -> TextPolicy:
    tl = d.get("train_levels")
    return TextPolicy(max_len=int(d["max_len"]), train_levels=None if tl is None else tuple(int(x) for x in tl),
                      eval_level=int(d["eval_level"]), cache_dtype=str(d.get("cache_dtype", "float16")))


def read_meta(root: str | os.PathLike) -> dict:
    root = Path(root)
    hint = (" (training has not finished: rerun the same `handx eval train-evaluator` command to resume)"
            if (root / "checkpoints").is_dir() else "")
    return read_format_meta(root / META_FILE, FORMAT, FORMAT_VERSION,
                            missing=f"not an evaluator checkpoint: missing {META_FILE}{hint}",
                            upgrade="; retrain it with `handx eval train-evaluator`")


def load_evaluator(root: str | os.PathLike, *, encoder: str | os.PathLike | None = None,
                   batch_size: int = 256) -> TrainedEvaluator:
    """Open an evaluator folder. The encoder folder recorded in it (or ``encoder``, e.g. after a move)
    is loaded and must have the recorded weight fingerprint; anything else is refused."""
    from handx_jax.text.t5 import load_hf_t5_encoder

    root = Path(root)
    meta = read_meta(root)
    cfg_d = dict(meta["evaluator_config"])
    stored_dim = cfg_d.pop("motion_dim", None)  # written by earlier versions; now derived from motion_input
    cfg = EvaluatorConfig(**cfg_d)
    if stored_dim is not None and stored_dim != cfg.motion_dim:
        raise DataError(f"evaluator_config.motion_dim is {stored_dim}, but motion_input {cfg.motion_input!r} has "
                        f"{cfg.motion_dim} features", path=root / META_FILE)
    policy = _policy_from_json(meta["text"])
    enc_path = Path(encoder) if encoder is not None else Path(meta["encoder"]["path"])
    enc = load_hf_t5_encoder(enc_path)
    want = meta["encoder"]["fingerprint"]
    if enc.fingerprint != want:
        raise DataError(f"encoder fingerprint mismatch: this evaluator was trained with text encoder {want}, but "
                        f"{enc_path} has fingerprint {enc.fingerprint} (different weights or config); use the "
                        f"encoder folder it was trained with (--encoder), or retrain the evaluator", path=enc_path)
    if enc.tokenizer.fingerprint != meta["encoder"]["tokenizer_fingerprint"]:
        raise DataError(f"tokenizer fingerprint mismatch: trained with {meta['encoder']['tokenizer_fingerprint']}, "
                        f"{enc_path} has {enc.tokenizer.fingerprint}", path=enc_path)
    with np.load(root / STATS_FILE, allow_pickle=False) as z:
        stats = rep.NormStats.from_npz_dict({k: z[k] for k in z.files}, "evaluator")
    template = _init_params(cfg, policy.max_len)
    params = read_params_msgpack(root / PARAMS_FILE, template)  # checksum verified; bad files name themselves
    return TrainedEvaluator(cfg=cfg, params=params, stats=stats, encoder=enc, policy=policy, meta=meta, root=root,
                            batch_size=batch_size)


def _init_params(cfg: EvaluatorConfig, text_len: int, rng: jax.Array | None = None):
    model = Evaluator(cfg)
    rng = jax.random.PRNGKey(0) if rng is None else rng
    x = jnp.zeros((1, cfg.frames, cfg.motion_dim))
    t = jnp.zeros((1, min(text_len, 8), cfg.text_dim))
    m = jnp.ones((1, min(text_len, 8)), bool)
    return jax.jit(lambda r: model.init(r, x, t, m))(rng)


def save_evaluator(root: str | os.PathLike, ev: TrainedEvaluator) -> Path:
    """Write params, stats and (last, marking completeness) evaluator.json into ``root``."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    write_params_msgpack(root / PARAMS_FILE, ev.params)  # with params.msgpack.sha256
    buf = io.BytesIO()
    np.savez(buf, **ev.stats.to_npz_dict("evaluator"))
    atomic_write_bytes(root / STATS_FILE, buf.getvalue())
    atomic_write_json(root / META_FILE, ev.meta)
    ev.root = root
    return root


# ------------------------------------------------------------------------------------------------
# Training


def model_config(preset: str, text_dim: int, overrides: Mapping[str, Any] | None = None) -> EvaluatorConfig:
    if preset not in PRESETS:
        raise ValueError(f"unknown evaluator preset {preset!r}; choose from {sorted(PRESETS)}")
    cfg = dataclasses.replace(PRESETS[preset], text_dim=int(text_dim))
    overrides = dict(overrides or {})
    names = {f.name for f in dataclasses.fields(EvaluatorConfig)}
    bad = sorted(set(overrides) - names)
    if bad:
        raise ValueError(f"unknown evaluator config key(s) {bad}; known: {sorted(names)}")
    return dataclasses.replace(cfg, **overrides)


def train_evaluator(data: str | os.PathLike, encoder: str | os.PathLike, out: str | os.PathLike, *,
                    preset: str = "small", steps: int = 3000, batch_size: int = 128, lr: float = 3e-4,
                    warmup: int = 200, weight_decay: float = 5e-6, schedule: str = "cosine",
                    policy: TextPolicy = TextPolicy(), overrides: Mapping[str, Any] | None = None, seed: int = 0,
                    log_every: int = 50, ckpt_every: int = 500, keep_checkpoints: int = 2,
                    wandb: str = "offline", force: bool = False, final_eval: bool = True, text_bucket: int = 16,
                    prefetch: int = 2,
                    metric_cfg: MetricConfig = MetricConfig(), log: Callable[[str], None] = print) -> Path:
    """Train an evaluator on the train split of ``data`` and write the checkpoint folder ``out``.

    Builds (or reuses) the joined text cache of ``data`` for ``encoder`` at ``policy.max_len``. An
    unfinished ``out`` (checkpoints, no evaluator.json) is resumed; a finished one is refused unless
    ``force`` (which retrains from scratch).
    """
    import shutil

    from handx_jax.data.dataset import Dataset, dataset_record
    from handx_jax.models.layers import count_params
    from handx_jax.text.cache import build_cache, open_cache
    from handx_jax.text.t5 import load_hf_t5_encoder
    from handx_jax.train import OptimConfig, TrainConfig, train

    out = Path(out)
    warmup = min(warmup, steps // 5)  # short (test/debug) runs: keep a decay phase after the warm-up
    if (out / META_FILE).exists():
        if not force:
            raise FileExistsError(f"{out} already holds a trained evaluator; pass --force (force=True) to retrain")
        shutil.rmtree(out)
    ds = Dataset.open(data)
    enc = load_hf_t5_encoder(encoder)
    levels = int(ds.meta.get("levels", len(ds.texts[0]["left"])))
    train_levels = tuple(range(levels)) if policy.train_levels is None else tuple(
        _level_index(lv, levels) for lv in policy.train_levels)
    _level_index(policy.eval_level, levels)
    build_cache(data, encoder, joined=True, max_len=policy.max_len, dtype=policy.cache_dtype, log=log)
    cache = open_cache(data, encoder, joined=True, max_len=policy.max_len, dtype=policy.cache_dtype)
    cfg = model_config(preset, enc.cfg.d_model, overrides)
    clips = ds.split("train")
    if len(clips) < 2:
        raise DataError(f"train split has {len(clips)} clips; the contrastive loss needs at least 2", path=ds.root)
    stats = evaluator_stats(ds, cfg.motion_input, clips)
    tdata = TrainingData(ds, cache, stats, clips, train_levels, seed, text_bucket, cfg.motion_input)
    model = Evaluator(cfg)
    Lmax = int(cache.meta["Lmax"])
    init = lambda rng: _init_params(cfg, Lmax, rng)  # noqa: E731
    n_params = count_params(jax.eval_shape(init, jax.random.PRNGKey(0)))
    truncated = _truncation(cache, clips, train_levels)
    tcfg = TrainConfig(steps=steps, batch_size=batch_size, seed=seed, log_every=log_every, ckpt_every=ckpt_every,
                       keep_checkpoints=keep_checkpoints, wandb=wandb, prefetch=prefetch,
                       optim=OptimConfig(lr=lr, warmup_steps=warmup, weight_decay=weight_decay, schedule=schedule))
    config = {"family": "evaluator", "run_id": out.name, "preset": preset, "model": dataclasses.asdict(cfg),
              "layers": cfg.layers, "dim": cfg.latent, "heads": cfg.heads, "ff": cfg.ff, "params": n_params,
              "text": dataclasses.asdict(policy), "train_levels": list(train_levels),
              "data": {"path": str(Path(data).absolute()), "fingerprint": ds.fingerprint},
              "encoder": {"path": str(Path(encoder).absolute()), "fingerprint": enc.fingerprint}}
    log(f"evaluator {preset}: {n_params:,} params, {len(clips)} train clips × levels {list(train_levels)}, "
        f"text Lmax {Lmax} ({100 * truncated:.1f}% of training captions truncated at {policy.max_len} tokens), "
        f"{steps} steps × batch {batch_size}")

    def loss(params, batch, rng, is_train):
        return evaluator_loss(model, params, batch, rng, is_train)

    def on_log(row):
        log(f"step {row['step']}: loss {row['loss']:.4f} infonce {row['infonce']:.4f} "
            f"({row['samples_per_s']:.0f} samples/s)")

    t0 = time.perf_counter()
    res = train(out, init=init, loss=loss, get_batch=tdata.batch, num_examples=len(tdata), cfg=tcfg,
                config=config, on_log=on_log)
    wall = time.perf_counter() - t0
    last = {}
    mpath = out / "metrics.jsonl"
    if mpath.exists():
        from handx_jax.io import read_jsonl

        rows = read_jsonl(mpath, strict=False)
        last = rows[-1] if rows else {}
    meta = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "preset": preset,
        "evaluator_config": dataclasses.asdict(cfg), "params": n_params,
        "text": {**dataclasses.asdict(policy), "train_levels": list(train_levels), "levels": levels,
                 "Lmax": Lmax, "truncated_fraction": truncated, "joined_format": joined_caption("L", "R", "I")},
        "dataset": {**dataset_record(ds), "path": str(Path(data).absolute()), "train_clips": len(clips)},
        "encoder": {"path": str(Path(encoder).absolute()), "fingerprint": enc.fingerprint,
                    "tokenizer_fingerprint": enc.tokenizer.fingerprint, "d_model": enc.cfg.d_model},
        "text_cache": {"fingerprint": cache.fingerprint, "dtype": policy.cache_dtype},
        "normalisation": (f"motion_input {cfg.motion_input!r} (representation.EVALUATOR_INPUTS; both start with "
                          f"the per-frame right-wrist centring) then (x - mean) / std of {STATS_FILE}"),
        "training": {"steps": int(res["step"]), "batch_size": batch_size, "lr": lr, "warmup": warmup,
                     "schedule": schedule, "weight_decay": weight_decay, "seed": seed,
                     "wall_seconds_this_process": wall,
                     "final": {k: last.get(k) for k in ("loss", "infonce", "kl", "latent", "recon") if k in last}},
    }
    ev = TrainedEvaluator(cfg=cfg, params=jax.device_get(res["params"]), stats=stats, encoder=enc, policy=policy,
                          meta=meta)
    save_evaluator(out, ev)
    log(f"wrote evaluator {out} ({wall:.0f} s)")
    if final_eval and len(ds.split("test")):
        result = evaluate_ground_truth(ev, ds, metric_cfg)
        write_eval_json(out / EVAL_FILE, result)
        log(format_table([("Ground Truth", result)], block=metric_cfg.rprec_block))
    return out


def _truncation(cache, clips: np.ndarray, levels: Sequence[int]) -> float:
    """Fraction of the training (clip, level) captions that fill all ``max_len`` tokens (i.e. were cut)."""
    if not cache.meta.get("num_truncated", 0):
        return 0.0
    rows = cache.row(np.asarray(clips)[:, None], JOINED, np.asarray(levels)[None, :]).reshape(-1)
    uniq, inv = np.unique(rows, return_inverse=True)
    full = np.asarray(cache.mask[uniq, -1], bool)
    return float(full[inv].mean())


# ------------------------------------------------------------------------------------------------
# Reference embeddings, cached in the evaluator folder
#
# Every evaluation of a sweep scores against the same reference: the captions of the reference clips at
# the evaluation level and their GT motion. Embedding them (the captions through the frozen T5 on the
# fly) costs far more than embedding the generated motion and computing the metrics, so the first
# evaluation stores them in ``E/reference_cache/<key hash>.npz`` and later ones read them back. The key
# holds everything the embeddings depend on (evaluator and encoder fingerprints, text policy, batch
# size, hashes of the exact captions and GT motion, clip indices, dataset fingerprint, evaluation level,
# JAX backend), so a cached file is bitwise what the uncached computation gives on the machine that
# wrote it, and anything else (another dataset, level, subset, retrained evaluator) misses. The key
# leaves out the host and JAX version on purpose: the CPU nodes of a sweep then share one fixed
# reference instead of each recomputing it up to float rounding.

REFERENCE_CACHE_DIR = "reference_cache"
REFERENCE_CACHE_VERSION = 1


@dataclass
class ReferenceEmbeddings:
    """μ-embeddings ``(N, latent)`` of the reference captions and GT motion of one evaluation.

    ``status``: "hit" (read from the cache), "miss" (computed, then written), "off" (computed, no cache
    folder), "unwritable" (computed; the cache folder could not be written, e.g. a read-only evaluator).
    ``seconds``: {"text", "motion"}; a hit books its key hashing and read time under "text".
    """

    text_NxD: np.ndarray
    motion_NxD: np.ndarray
    status: str
    seconds: dict
    path: Path | None = None


def _digest(*chunks: bytes) -> str:
    h = hashlib.sha256()
    for c in chunks:
        h.update(c)
    return h.hexdigest()[:16]


def reference_key(ev: TrainedEvaluator, texts: Sequence[str], gt_NxTx2x21x3: np.ndarray,
                  provenance: Mapping[str, Any] | None = None) -> dict:
    """The cache key of the reference embeddings of joined captions ``texts`` and GT motion.

    The batch size is part of it because the text side pads each chunk to its own length bucket, which
    moves embeddings by float rounding; ``provenance`` (dataset fingerprint, evaluation level, clips) is
    redundant with the content hashes but makes a file's origin readable and keeps datasets apart.
    """
    return {
        "version": REFERENCE_CACHE_VERSION,
        "evaluator": ev.fingerprint,
        "encoder": ev.encoder.fingerprint,
        "tokenizer": ev.encoder.tokenizer.fingerprint,
        "text_policy": {"max_len": ev.policy.max_len, "cache_dtype": ev.policy.cache_dtype},
        "batch_size": int(ev.batch_size),
        "n": len(texts),
        "captions": _digest(json.dumps(list(texts)).encode()),
        "motion": _digest(np.ascontiguousarray(gt_NxTx2x21x3, np.float32).tobytes()),
        "provenance": dict(provenance or {}),
        "backend": jax.default_backend(),
    }


def _key_json(key: Mapping) -> str:
    return json.dumps(key, sort_keys=True)


def read_reference_cache(path: Path, key: Mapping, latent: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(text, motion) from ``path`` if it holds exactly ``key``; None when absent, unreadable or stale."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != _key_json(key):
                return None
            text, motion = z["text_NxD"], z["motion_NxD"]
    except Exception:  # noqa: BLE001  (missing, truncated, not a zip, missing arrays: all just a miss)
        return None
    want = (int(key["n"]), latent)
    if text.shape != want or motion.shape != want or text.dtype != np.float32 or motion.dtype != np.float32:
        return None
    return text, motion


def write_reference_cache(path: Path, key: Mapping, text_NxD: np.ndarray, motion_NxD: np.ndarray) -> bool:
    """Atomically write the cache file (concurrent evaluations race harmlessly); False if it cannot be."""
    buf = io.BytesIO()
    np.savez(buf, key=np.asarray(_key_json(key)), text_NxD=np.asarray(text_NxD, np.float32),
             motion_NxD=np.asarray(motion_NxD, np.float32))
    try:
        atomic_write_bytes(path, buf.getvalue())
    except OSError:
        return False
    return True


def _cache_folder(ev: TrainedEvaluator, cache: bool | str | os.PathLike) -> Path | None:
    if cache is False or cache is None:
        return None
    if cache is True:
        return None if ev.root is None else Path(ev.root) / REFERENCE_CACHE_DIR
    return Path(cache)


def reference_embeddings(ev: TrainedEvaluator, prompts: tuple[Sequence[str], Sequence[str], Sequence[str]],
                         gt_NxTx2x21x3: np.ndarray, *, provenance: Mapping[str, Any] | None = None,
                         cache: bool | str | os.PathLike = True) -> ReferenceEmbeddings:
    """Text μ of the (left, right, interaction) ``prompts`` and motion μ of their GT clips, cached.

    ``cache``: True = the evaluator folder's ``reference_cache/`` (no cache for an evaluator without a
    folder), False = compute without reading or writing any cache, a path = that folder.
    """
    gt = np.asarray(gt_NxTx2x21x3, np.float32)
    folder = _cache_folder(ev, cache)
    t0 = time.perf_counter()
    key = path = None
    if folder is not None:
        key = reference_key(ev, [joined_caption(*p) for p in zip(*prompts)], gt, provenance)
        path = folder / f"{_digest(_key_json(key).encode())}.npz"
        hit = read_reference_cache(path, key, ev.cfg.latent)
        if hit is not None:
            return ReferenceEmbeddings(hit[0], hit[1], "hit", {"text": time.perf_counter() - t0, "motion": 0.0},
                                       path)
    text = ev.embed_text(*prompts)
    t1 = time.perf_counter()
    motion = ev.embed_motion(gt)
    t2 = time.perf_counter()
    status = "off"
    if path is not None:
        status = "miss" if write_reference_cache(path, key, text, motion) else "unwritable"
    return ReferenceEmbeddings(text, motion, status, {"text": t1 - t0, "motion": t2 - t1}, path)


# ------------------------------------------------------------------------------------------------
# Evaluation


@dataclass
class EvalResult:
    metrics: dict[str, tuple[float, float]]
    meta: dict

    def flat(self) -> dict[str, float]:
        """``{name: mean, name_ci: half-width}`` with the analysis schema's metric names."""
        out: dict[str, float] = {}
        for k, (m, c) in self.metrics.items():
            out[k], out[f"{k}_ci"] = float(m), float(c)
        return out


def _schema_names(motion: dict) -> dict:
    # replicate_motion_metrics names contacts contact_<p|r|f1>_<intra|inter>; the schema spells them out.
    ren = {"precision": "precision", "recall": "recall", "f1": "f1"}
    out = {}
    for k, v in motion.items():
        if k.startswith("contact_"):
            _, what, scope = k.split("_")
            out[f"contact_{ren[what]}_{scope}"] = v
        else:
            out[k] = v
    return out


def evaluate_embeddings_and_motion(ev: TrainedEvaluator, text_NxD: np.ndarray, gen_GxNxTx2x21x3: np.ndarray,
                                   gt_NxTx2x21x3: np.ndarray, cfg: MetricConfig, *,
                                   gt_NxD: np.ndarray | None = None, gen_GxNxD: np.ndarray | None = None,
                                   meta: dict | None = None) -> EvalResult:
    """All metrics of G generation groups against the GT; motion embeddings given are not recomputed
    (the reference cache's GT embeddings; the GT row's generation, which is the GT)."""
    t0 = time.perf_counter()
    G, N = gen_GxNxTx2x21x3.shape[:2]
    gt_emb = ev.embed_motion(gt_NxTx2x21x3) if gt_NxD is None else gt_NxD
    if gen_GxNxD is None:
        gen_GxNxD = np.stack([ev.embed_motion(gen_GxNxTx2x21x3[g]) for g in range(G)])
    gen_emb = np.asarray(gen_GxNxD, np.float32)
    t1 = time.perf_counter()
    emb = replicate_embedding_metrics(text_NxD, gen_emb, gt_emb, cfg)
    mot = _schema_names(replicate_motion_metrics(gen_GxNxTx2x21x3, gt_NxTx2x21x3, cfg))
    t2 = time.perf_counter()
    order = ("rprec_top1", "rprec_top2", "rprec_top3", "fid", "mm_dist", "diversity", "multimodality", "mpjpe",
             "acceleration", "jitter", "contact_precision_intra", "contact_recall_intra", "contact_f1_intra",
             "contact_precision_inter", "contact_recall_inter", "contact_f1_inter")
    allm = {**emb, **mot}
    metrics = {k: allm[k] for k in order if k in allm}
    m = {"prompts": int(N), "groups": int(G), "replications": cfg.replications, "rprec_block": cfg.rprec_block,
         "seed": cfg.seed, "mpjpe_root": cfg.mpjpe_root, "evaluator": str(ev.root) if ev.root else None,
         "eval_level": ev.policy.eval_level, "seconds": {"motion_embedding": t1 - t0, "metrics": t2 - t1},
         **(meta or {})}
    return EvalResult(metrics, m)


def _dataset_reference(ev: TrainedEvaluator, ds, clips: np.ndarray, cache: bool | str | os.PathLike):
    """GT motion and (cached) reference embeddings of ``clips`` of ``ds`` at the evaluator's caption level."""
    gt = np.asarray(ds.motion[clips], np.float32)
    provenance = {"dataset": ds.fingerprint, "eval_level": ev.policy.eval_level,
                  "clips": _digest(np.asarray(clips, np.int64).tobytes())}
    return gt, reference_embeddings(ev, ev.captions(ds, clips), gt, provenance=provenance, cache=cache)


def _note_reference(res: EvalResult, ref: ReferenceEmbeddings) -> EvalResult:
    """Booked in meta: text seconds (the cache read on a hit), GT motion seconds, the cache status."""
    res.meta["seconds"]["text_embedding"] = ref.seconds["text"]
    res.meta["seconds"]["motion_embedding"] += ref.seconds["motion"]
    res.meta["reference_cache"] = ref.status
    return res


def evaluate_ground_truth(ev: TrainedEvaluator, ds, cfg: MetricConfig = MetricConfig(), split: str = "test", *,
                          cache: bool | str | os.PathLike = True) -> EvalResult:
    """The "Ground Truth" row: the split's GT motion scored as if it were the generation (G = 1).

    ``cache``: where the reference embeddings are cached (:func:`reference_embeddings`); False bypasses it.
    """
    ev.check_dataset(ds)
    clips = np.sort(ds.split(split))
    if len(clips) < 2:
        raise DataError(f"split {split!r} has {len(clips)} clips; need at least 2", path=ds.root)
    gt, ref = _dataset_reference(ev, ds, clips, cache)
    res = evaluate_embeddings_and_motion(ev, ref.text_NxD, gt[None], gt, cfg, gt_NxD=ref.motion_NxD,
                                         gen_GxNxD=ref.motion_NxD[None],
                                         meta={"split": split, "ground_truth": True, "reference": str(ds.root)})
    return _note_reference(res, ref)


@dataclass
class Generated:
    """Generated clips aligned to reference prompts: motion (G, N, T, 2, 21, 3) for clips ``clips`` (N,)."""

    motion: np.ndarray
    clips: np.ndarray
    keys: list[list[str]]


def align_generated(entries: Sequence, ds, split: str = "test") -> Generated:
    """Arrange generated :class:`~handx_jax.data.handx_npz.HandXClip` entries as (group, prompt).

    With ``source_clip`` on every entry, it names the reference clip (any split); ``group`` defaults
    to the entry's occurrence index among entries of the same source clip. Without ``source_clip`` on
    any entry, entry i is taken as generation i // N of clip i mod N of the reference ``split`` (in
    split order). Every group must cover the same prompts; captions stored in an entry must be the
    reference clip's captions (all levels, or a subset of them), which catches misaligned files.
    """
    if not entries:
        raise DataError("no generated clips")
    has = [e.source_clip is not None for e in entries]
    if any(has) and not all(has):
        bad = next(e.key for e, h in zip(entries, has) if not h)
        raise DataError("some entries carry source_clip and some do not; either all or none must", clip=bad,
                        field="source_clip")
    id_to_idx = {cid: i for i, cid in enumerate(ds.ids)}
    cells: dict[tuple[int, int], Any] = {}
    if all(has):
        seen: dict[int, int] = {}
        for e in entries:
            if e.source_clip not in id_to_idx:
                raise DataError(f"source_clip {e.source_clip!r} is not a clip of the reference dataset {ds.root}",
                                clip=e.key, field="source_clip")
            c = id_to_idx[e.source_clip]
            g = e.group if e.group is not None else seen.get(c, 0)
            seen[c] = max(seen.get(c, 0), g + 1)
            if (g, c) in cells:
                raise DataError(f"duplicate (source_clip {e.source_clip!r}, group {g})", clip=e.key, field="group")
            cells[(g, c)] = e
    else:
        order = np.asarray(ds.split(split))
        n = len(order)
        if n == 0 or len(entries) % n:
            raise DataError(f"{len(entries)} entries without source_clip cannot be matched to the {n} clips of the "
                            f"reference {split!r} split (need a multiple of {n}); write source_clip per entry")
        for i, e in enumerate(entries):
            cells[(i // n, int(order[i % n]))] = e
    groups = sorted({g for g, _ in cells})
    if groups != list(range(len(groups))):
        raise DataError(f"generation groups must be 0..G-1, got {groups}", field="group")
    clips = np.array(sorted({c for _, c in cells}), np.int64)
    for g in groups:
        missing = [ds.ids[c] for c in clips if (g, c) not in cells]
        if missing:
            raise DataError(f"group {g} lacks {len(missing)} of the {len(clips)} prompts (e.g. {missing[:3]}); "
                            "every group must cover the same prompts", field="group")
    G, N = len(groups), len(clips)
    T = entries[0].motion.shape[0]
    motion = np.zeros((G, N, T, 2, 21, 3), np.float32)
    keys = [[""] * N for _ in range(G)]
    for (g, c), e in cells.items():
        j = int(np.searchsorted(clips, c))
        if e.motion.shape != motion.shape[2:]:
            raise DataError(f"motion shape {e.motion.shape}, expected {motion.shape[2:]}", clip=e.key, field="motion")
        _check_captions(e, ds.texts[c])
        motion[g, j], keys[g][j] = e.motion, e.key
    return Generated(motion, clips, keys)


def _check_captions(entry, ref: dict) -> None:
    for name, have in (("left", entry.left), ("right", entry.right), ("interaction", entry.interaction)):
        want = ref[name]
        ok = have == want if len(have) == len(want) else all(s in want for s in have)
        if not ok:
            raise DataError(f"captions differ from reference clip {ref.get('id')!r} (generated for another prompt, "
                            f"or source_clip/order is wrong)", clip=entry.key, field=f"{name}_annotation")


def evaluate_generated(ev: TrainedEvaluator, entries: Sequence, ds, cfg: MetricConfig = MetricConfig(),
                       split: str = "test", *, cache: bool | str | os.PathLike = True) -> EvalResult:
    """Table 2 metrics of generated clips against the reference dataset's GT and captions.

    ``cache``: where the reference embeddings are cached (:func:`reference_embeddings`); False bypasses it.
    """
    ev.check_dataset(ds)
    gen = align_generated(entries, ds, split)
    gt, ref = _dataset_reference(ev, ds, gen.clips, cache)
    res = evaluate_embeddings_and_motion(ev, ref.text_NxD, gen.motion, gt, cfg, gt_NxD=ref.motion_NxD,
                                         meta={"ground_truth": False, "reference": str(ds.root)})
    return _note_reference(res, ref)


# ------------------------------------------------------------------------------------------------
# Output


TABLE_COLUMNS = (  # (metric, header) in the paper's Table 2 order, plus MPJPE and contact F1
    ("rprec_top1", "Top-1"), ("rprec_top2", "Top-2"), ("rprec_top3", "Top-3"), ("fid", "FID"),
    ("mm_dist", "MM-Dist"), ("diversity", "Diversity"), ("multimodality", "MModality"), ("mpjpe", "MPJPE(mm)"),
    ("contact_f1_intra", "F1-intra"), ("contact_f1_inter", "F1-inter"),
)


def format_table(rows: Sequence[tuple[str, EvalResult]], block: int = 32) -> str:
    """Rows in the paper's Table 2 layout: mean±CI (95%, 1.96·σ/√n over replications)."""
    w_name = max(14, *(len(n) for n, _ in rows))
    cells = [[f"{r.metrics[k][0]:.3f}±{r.metrics[k][1]:.3f}" if k in r.metrics else "-" for k, _ in TABLE_COLUMNS]
             for _, r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, (_, h) in enumerate(TABLE_COLUMNS)]
    span = sum(widths[:3]) + 4
    lines = [" " * w_name + "  " + f"R-Precision (block {block}) ↑".ljust(span) + "  "
             + "  ".join(h.ljust(w) for (_, h), w in list(zip(TABLE_COLUMNS, widths))[3:]),
             " " * w_name + "  " + "  ".join(h.ljust(w) for (_, h), w in list(zip(TABLE_COLUMNS, widths))[:3])]
    for (name, _), c in zip(rows, cells):
        lines.append(name.ljust(w_name) + "  " + "  ".join(x.ljust(w) for x, w in zip(c, widths)))
    return "\n".join(lines)


def write_eval_json(path: str | os.PathLike, result: EvalResult) -> Path:
    """``eval.json`` as the analysis run-folder contract reads it: ``name``/``name_ci`` plus ``_meta``."""
    return atomic_write_json(path, {**result.flat(), "_meta": result.meta})
