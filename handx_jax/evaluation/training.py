"""Training the evaluator: its run config (a config of ``handx_jax.config``, with presets) and the
training run, through the one training loop (``handx_jax.train``).

    cfg = make_evaluator_config("small", ["train.steps=8000", "text.train_levels=none"], data=DIR, encoder=ENC)
    train_evaluator(OUT, cfg)

The run folder is the loop's (``config.json``, ``metrics.jsonl``, ``checkpoints/``; resumable, and a
resume with a different configuration is refused) plus the checkpoint files of
``evaluation.checkpoint`` written at the end. The T5 encoder is loaded once and passed to the text
cache and the checkpoint (pass an already loaded one as ``encoder=``).
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import jax
import numpy as np

from handx_jax.config import ConfigError, apply_overrides, get_preset, to_dict
from handx_jax.evaluation.checkpoint import EVAL_FILE, FORMAT, FORMAT_VERSION, META_FILE, STATS_FILE, save_evaluator
from handx_jax.evaluation.features import JOINED, TextPolicy, TrainingData, _level_index, evaluator_stats, joined_caption
from handx_jax.evaluation.model import TrainedEvaluator, _init_params
from handx_jax.infra.errors import DataError
from handx_jax.metrics import MetricConfig
from handx_jax.models.evaluator import PRESETS, Evaluator, EvaluatorConfig, evaluator_loss
from handx_jax.train import OptimConfig, TrainConfig

TRAINABLE = "evaluator"  # config.json's "trainable": `handx train evaluator` (families.TRAINABLES)


@dataclass(frozen=True)
class EvaluatorDataConfig:
    path: str = ""  # dataset directory (trains on its train split)
    encoder: str = ""  # frozen T5 encoder folder
    # Text of a batch trimmed to its longest caption rounded up to this many tokens (see TrainingData.batch).
    text_bucket: int = 16
    # Caption-preserving augmentation of the training motion (issue 40; 0 = off, v4): each clip gets
    # white noise on its finger joints with a per-clip σ uniform in [0, augment_white_mm] mm, and
    # low-frequency noise (Gaussian-filtered over time, σ 4 frames) with RMS uniform in
    # [0, augment_lowfreq_mm] mm (validity.perturb's kinds, at amplitudes the validity suite measures).
    augment_white_mm: float = 0.0
    augment_lowfreq_mm: float = 0.0
    # The order of events as data (issue 40; "" / 0 = off, v5): a ``handx data reverse`` dataset of this
    # corpus's train clips played backwards with their own captions, and the share of each batch drawn
    # from it (features.TrainingData). Normalised with this corpus's statistics.
    reversed_path: str = ""
    reversed_share: float = 0.0
    # Paired: the last share of each batch is the reversals of its first items (a clip and its own reversal,
    # with their two captions, in one batch) instead of random reversed clips; share ≤ 0.5.
    reversed_pairs: bool = False


@dataclass(frozen=True)
class EvaluatorRunConfig:
    preset: str = "small"
    model: EvaluatorConfig = PRESETS["small"]
    text: TextPolicy = TextPolicy(train_levels=(0,))
    # The warm-up is capped at steps // 5 at training time, so short (test/debug) runs keep a decay phase.
    train: TrainConfig = TrainConfig(steps=3000, batch_size=128, seed=0, log_every=50, ckpt_every=500,
                                     optim=OptimConfig(lr=3e-4, warmup_steps=200, weight_decay=5e-6,
                                                       schedule="cosine"))
    data: EvaluatorDataConfig = field(default_factory=EvaluatorDataConfig)
    final_eval: bool = True  # score the Ground Truth row on the test split when training ends
    # Fine-tuning: an evaluator folder whose weights and input statistics this run starts from ("" = a
    # fresh initialisation). Its model must have this run's shape (the loss options may differ).
    init_from: str = ""
    metrics: MetricConfig = MetricConfig()  # for that row

    def validate(self) -> None:
        m = self.model
        if m.latent % m.heads:
            raise ConfigError(f"model.latent {m.latent} is not divisible by model.heads {m.heads}")
        if self.train.optim.schedule not in ("constant", "cosine"):
            raise ConfigError(f"train.optim.schedule must be 'constant' or 'cosine', got {self.train.optim.schedule!r}")
        if self.text.max_len < 2:
            raise ConfigError(f"text.max_len must be >= 2, got {self.text.max_len}")
        if self.data.augment_white_mm < 0 or self.data.augment_lowfreq_mm < 0:
            raise ConfigError("data.augment_white_mm and data.augment_lowfreq_mm must be >= 0 (mm)")
        if not 0.0 <= self.data.reversed_share < 1.0:
            raise ConfigError(f"data.reversed_share must be in [0, 1), got {self.data.reversed_share}")
        if self.data.reversed_pairs and self.data.reversed_share > 0.5:
            raise ConfigError(f"data.reversed_pairs pairs the first items of a batch with reversals in its last ones: "
                              f"data.reversed_share must be <= 0.5, got {self.data.reversed_share}")
        from handx_jax.validity.perturb import HARD_NEGATIVE_KINDS

        bad = [k for k in m.hard_negatives if k not in HARD_NEGATIVE_KINDS]
        if bad or len(set(m.hard_negatives)) != len(m.hard_negatives):
            raise ConfigError(f"model.hard_negatives {','.join(m.hard_negatives)}: "
                              f"{'unknown ' + ','.join(bad) if bad else 'a kind named twice'}; choose from "
                              f"{', '.join(HARD_NEGATIVE_KINDS)} (validity.perturb's edits of a clip's own motion)")
        if (self.data.reversed_share > 0) != bool(self.data.reversed_path):
            raise ConfigError("data.reversed_path and data.reversed_share > 0 go together (a `handx data reverse` "
                              "dataset and the share of each batch drawn from it)")


def make_evaluator_config(preset: str = "small", overrides: Sequence[str] = (), *, data: str = "",
                          encoder: str = "") -> EvaluatorRunConfig:
    """The evaluator run config of a named preset (``models.evaluator.PRESETS``) with dotted overrides."""
    cfg = EvaluatorRunConfig(preset=preset, model=get_preset(PRESETS, preset, "evaluator preset"),
                             data=EvaluatorDataConfig(path=str(Path(data).absolute()) if data else "",
                                                      encoder=str(Path(encoder).absolute()) if encoder else ""))
    return apply_overrides(cfg, overrides)


def model_config(preset: str, text_dim: int, overrides=None) -> EvaluatorConfig:
    """A preset's model config at ``text_dim`` with field overrides (a mapping or ``key=value`` strings)."""
    cfg = dataclasses.replace(get_preset(PRESETS, preset, "evaluator preset"), text_dim=int(text_dim))
    if isinstance(overrides, dict):
        overrides = [f"{k}={v}" for k, v in overrides.items()]
    return apply_overrides(cfg, list(overrides or ()))


def train_evaluator(out: str | os.PathLike, cfg: EvaluatorRunConfig, *, encoder=None, force: bool = False,
                    stop_at: int | None = None, log: Callable[[str], None] = print) -> Path:
    """Train an evaluator on the train split of ``cfg.data.path`` and write the checkpoint folder ``out``.

    Builds (or reuses) the joined text cache for the encoder at ``cfg.text.max_len``. An unfinished
    ``out`` (checkpoints, no evaluator.json) is resumed (same config only); a finished one is refused
    unless ``force`` (which retrains from scratch). ``encoder``: an already loaded FrozenEncoder of
    ``cfg.data.encoder`` (loaded here otherwise, once). ``stop_at`` ends early as if killed (tests).
    """
    import shutil

    from handx_jax.dataset.format import Dataset, dataset_record
    from handx_jax.evaluation.scoring import evaluate_ground_truth, format_table, write_eval_json
    from handx_jax.models.layers import count_params
    from handx_jax.text.cache import build_cache, open_cache
    from handx_jax.text.hf import as_encoder
    from handx_jax.runlog import trainable_renamed
    from handx_jax.train import TrainSpec, train

    cfg.validate()
    out = Path(out)
    policy, data = cfg.text, cfg.data.path
    if not data or not cfg.data.encoder and encoder is None:
        raise ConfigError("the evaluator run config needs data.path and data.encoder")
    if (out / META_FILE).exists():
        if not force:
            raise FileExistsError(f"{out} already holds a trained evaluator; pass --force (force=True) to retrain")
        shutil.rmtree(out)
    ds = Dataset.open(data)
    enc = as_encoder(encoder if encoder is not None else cfg.data.encoder)
    enc_path = str(Path(enc.path or cfg.data.encoder).absolute())
    levels = int(ds.meta.get("levels", len(ds.texts[0]["left"])))
    train_levels = tuple(range(levels)) if policy.train_levels is None else tuple(
        _level_index(lv, levels) for lv in policy.train_levels)
    eval_level = _level_index(policy.eval_level, levels)
    # Only the levels the run reads are encoded (a full joined cache, where one exists, serves too): trained
    # and scored at level 0, a fifth of the full cache (600k captions of a 120k corpus took 149 s on an H200).
    read = sorted(set(train_levels) | {eval_level})
    build_cache(data, enc, joined=True, max_len=policy.max_len, dtype=policy.cache_dtype, levels=read, log=log)
    cache = open_cache(data, enc, joined=True, max_len=policy.max_len, dtype=policy.cache_dtype, levels=read)
    mcfg = dataclasses.replace(cfg.model, text_dim=enc.cfg.d_model)
    clips = ds.split("train")
    if len(clips) < 2:
        raise DataError(f"train split has {len(clips)} clips; the contrastive loss needs at least 2", path=ds.root)
    tcfg = cfg.train
    tcfg = dataclasses.replace(tcfg, optim=dataclasses.replace(
        tcfg.optim, warmup_steps=min(tcfg.optim.warmup_steps, tcfg.steps // 5)))
    start = _start_from(cfg.init_from, mcfg, enc) if cfg.init_from else None
    stats = start.stats if start is not None else evaluator_stats(ds, mcfg.motion_input, clips)
    companion = _companion(cfg.data.reversed_path, ds, enc, policy, read, log) if cfg.data.reversed_share > 0 else None
    tdata = TrainingData(ds, cache, stats, clips, train_levels, tcfg.seed, cfg.data.text_bucket, mcfg.motion_input,
                         augment_white_m=cfg.data.augment_white_mm / 1000, augment_lowfreq_m=cfg.data.augment_lowfreq_mm / 1000,
                         reversed_copy=mcfg.reverse_negative, text_ids=mcfg.mask_same_text,
                         companion=companion, companion_share=cfg.data.reversed_share,
                         companion_pairs=cfg.data.reversed_pairs, hard_negatives=mcfg.hard_negatives)
    model = Evaluator(mcfg)
    Lmax = int(cache.meta["Lmax"])
    if start is not None:
        init = lambda rng: jax.tree_util.tree_map(jax.numpy.asarray, start.params)  # noqa: E731
    else:
        init = lambda rng: _init_params(mcfg, Lmax, rng)  # noqa: E731
    n_params = count_params(jax.eval_shape(init, jax.random.PRNGKey(0)))
    truncated = _truncation(cache, clips, train_levels)
    config = {"trainable": TRAINABLE, "run_id": out.name, "preset": cfg.preset, "model": dataclasses.asdict(mcfg),
              "layers": mcfg.layers, "dim": mcfg.latent, "heads": mcfg.heads, "ff": mcfg.ff, "params": n_params,
              "text": to_dict(policy), "train_levels": list(train_levels),
              "data": {"path": str(Path(data).absolute()), "fingerprint": ds.fingerprint,
                       "text_bucket": cfg.data.text_bucket,
                       **({"reversed": {"path": str(Path(cfg.data.reversed_path).absolute()),
                                        "fingerprint": companion[0].fingerprint, "share": cfg.data.reversed_share,
                                        **({"pairs": True} if cfg.data.reversed_pairs else {})}}
                          if companion else {})},
              **({"init_from": {"path": str(Path(cfg.init_from).absolute()),
                                "fingerprint": start.fingerprint}} if start else {}),
              "encoder": {"path": enc_path, "fingerprint": enc.fingerprint}}
    log(f"evaluator {cfg.preset}: {n_params:,} params, {len(clips)} train clips × levels {list(train_levels)}, "
        f"text Lmax {Lmax} ({100 * truncated:.1f}% of training captions truncated at {policy.max_len} tokens), "
        f"{tcfg.steps} steps × batch {tcfg.batch_size}"
        + (f"; hard negatives {', '.join(mcfg.hard_negatives)}" if mcfg.hard_negatives else ""))

    def loss(params, batch, rng, is_train):
        return evaluator_loss(model, params, batch, rng, is_train)

    def on_log(row):
        if "loss" in row:
            log(f"step {row['step']}: loss {row['loss']:.4f} infonce {row['infonce']:.4f} "
                f"({row['samples_per_s']:.0f} samples/s)")

    t0 = time.perf_counter()
    # Evaluator runs written before issue 42 said "family": "evaluator"; they resume as this trainable.
    res = train(out, TrainSpec(init=init, loss=loss, cfg=tcfg, config=config, get_batch=tdata.batch,
                               num_examples=len(tdata), upgrade_config=trainable_renamed("evaluator", TRAINABLE)),
                on_log=on_log, stop_at=stop_at)
    wall = time.perf_counter() - t0
    if res["step"] < tcfg.steps:  # stopped early (stop_at): the folder stays resumable, no checkpoint files
        return out
    last = {}
    mpath = out / "metrics.jsonl"
    if mpath.exists():
        from handx_jax.infra.readers import read_jsonl

        rows = [r for r in read_jsonl(mpath, strict=False) if "loss" in r]
        last = rows[-1] if rows else {}
    o = tcfg.optim
    meta = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "preset": cfg.preset,
        "evaluator_config": dataclasses.asdict(mcfg), "params": n_params,
        "text": {**dataclasses.asdict(policy), "train_levels": list(train_levels), "levels": levels,
                 "Lmax": Lmax, "truncated_fraction": truncated, "joined_format": joined_caption("L", "R", "I")},
        "dataset": {**dataset_record(ds), "path": str(Path(data).absolute()), "train_clips": len(clips)},
        "encoder": {"path": enc_path, "fingerprint": enc.fingerprint,
                    "tokenizer_fingerprint": enc.tokenizer.fingerprint, "d_model": enc.cfg.d_model},
        "text_cache": {"fingerprint": cache.fingerprint, "dtype": policy.cache_dtype},
        "normalisation": (f"motion_input {mcfg.motion_input!r} (representation.EVALUATOR_INPUTS; both start with "
                          f"the per-frame right-wrist centring) then (x - mean) / std of {STATS_FILE}"),
        "training": {"steps": int(res["step"]), "batch_size": tcfg.batch_size, "lr": o.lr, "warmup": o.warmup_steps,
                     "schedule": o.schedule, "weight_decay": o.weight_decay, "seed": tcfg.seed,
                     "wall_seconds_this_process": wall,
                     **{k: config[k] for k in ("init_from",) if k in config},
                     **({"reversed": config["data"]["reversed"]} if "reversed" in config["data"] else {}),
                     "final": {k: last.get(k) for k in ("loss", "infonce", "kl", "latent", "recon") if k in last}},
    }
    ev = TrainedEvaluator(cfg=mcfg, params=jax.device_get(res["params"]), stats=stats, encoder=enc, policy=policy,
                          meta=meta)
    save_evaluator(out, ev)
    log(f"wrote evaluator {out} ({wall:.0f} s)")
    if cfg.final_eval and len(ds.split("test")):
        result = evaluate_ground_truth(ev, ds, cfg.metrics)
        write_eval_json(out / EVAL_FILE, result)
        log(format_table([("Ground Truth", result)], block=cfg.metrics.rprec_block))
    return out


def _start_from(path: str, mcfg: EvaluatorConfig, enc):
    """The evaluator a fine-tuning run starts from; its model must have ``mcfg``'s shape."""
    from handx_jax.evaluation.checkpoint import load_evaluator

    start = load_evaluator(path, encoder=enc)
    shape = ("latent", "layers", "heads", "ff", "motion_input", "motion_patch", "text_dim", "frames", "recon")
    diff = [f"{k} {getattr(start.cfg, k)!r} vs {getattr(mcfg, k)!r}" for k in shape
            if getattr(start.cfg, k) != getattr(mcfg, k)]
    if diff:
        raise ConfigError(f"init_from {path}: its model differs from this run's ({'; '.join(diff)}); "
                          "fine-tuning needs the same shape (pick its preset and overrides)")
    return start


def _companion(path: str, ds, enc, policy: TextPolicy, levels: Sequence[int], log):
    """(dataset, joined cache) of the reversed copy ``path`` of ``ds`` (``handx data reverse``)."""
    from handx_jax.dataset.format import Dataset
    from handx_jax.text.cache import build_cache, open_cache

    rds = Dataset.open(path)
    src = rds.meta.get("source") or {}
    if src.get("kind") != "reversed" or src.get("of_fingerprint") != ds.fingerprint:
        raise DataError(f"data.reversed_path is not a `handx data reverse` copy of {ds.root} (its meta.json source "
                        f"names {src.get('of') or 'no such dataset'})", path=Path(path) / "meta.json")
    build_cache(path, enc, joined=True, max_len=policy.max_len, dtype=policy.cache_dtype, levels=levels, log=log)
    return rds, open_cache(path, enc, joined=True, max_len=policy.max_len, dtype=policy.cache_dtype, levels=levels)


def _truncation(cache, clips: np.ndarray, levels: Sequence[int]) -> float:
    """Fraction of the training (clip, level) captions that fill all ``max_len`` tokens (i.e. were cut)."""
    if not cache.meta.get("num_truncated", 0):
        return 0.0
    rows = cache.row(np.asarray(clips)[:, None], JOINED, np.asarray(levels)[None, :]).reshape(-1)
    uniq, inv = np.unique(rows, return_inverse=True)
    full = np.asarray(cache.mask[uniq, -1], bool)
    return float(full[inv].mean())
