"""The diffusion family: run config, training glue, and loading a trained run for sampling.

A run is ``DiffusionRunConfig`` = preset-derived ``DiTConfig`` + ``DiffusionConfig`` + ``TrainConfig``
+ ``DataConfig``, changed with dotted ``--set key=value`` overrides (type-checked; unknown keys are an
error with a suggestion). Training items are (clip, level) pairs of the train split's nested data
fraction; item j of a clip uses annotation level j for all three texts, as the reference loader does
(reference §1.2). The normalised diffusion representation of every training clip is computed once and
held in memory; text comes from the frozen-encoder cache (the encoder never runs in the step). Each
branch's text is dropped to the null embedding independently with p = ``cond_drop`` (§3.2); t is
uniform; the loss is the x0 objective of §3.5.

The run folder follows ``analysis.schema``'s contract: ``config.json`` holds ``family``, the model
axes (under ``model``), ``data_fraction``, ``params``, ``params_non_embedding``, ``flops_per_sample``
and ``text_flops_per_sample``; ``metrics.jsonl`` logs the cumulative ``train_flops``. The run also
keeps ``norm_stats.npz`` so generation does not need the dataset.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import os
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax import diffusion as D
from handx_jax.io import DataError
from handx_jax.models.dit import PRESETS, DiTConfig, TrebleDenoiser, forward_flops, init_denoiser, param_count
from handx_jax.train import OptimConfig, TrainConfig

FAMILY = "diffusion"
FIELDS = ("left", "right", "interaction")
NORM_FILE = "norm_stats.npz"


@dataclass(frozen=True)
class DataConfig:
    path: str = ""  # dataset directory
    encoder: str = ""  # frozen T5 encoder folder (its text cache must exist in the dataset)
    fraction: float = 1.0  # nested train subset (0.05 / 0.2 / 1.0 in the default build)
    # How ``fraction`` picks training items (reference §1.2). "clips": the nested clip subsets
    # (5% ⊂ 20% ⊂ 100% of clips), each clip with all its caption levels. "pairs": the reference's
    # rule: a fraction of all (clip, caption level) items, np.random.RandomState(42).choice without
    # replacement (= the first k of one permutation, so also nested); a clip may keep only some levels.
    sampling: str = "clips"
    text_max_len: int = 128  # the text cache's max_len
    cache_dtype: str = "float16"


@dataclass(frozen=True)
class DiffusionRunConfig:
    preset: str = "tiny"
    model: DiTConfig = PRESETS["tiny"]
    diffusion: D.DiffusionConfig = D.DiffusionConfig()
    # Reference §3.6: AdamW(1e-4, (0.9, 0.95), wd 5e-6 on ndim ≥ 2), constant LR; we add a short
    # warm-up, clip before the update, and keep EMA weights (warmed-up decay, so short runs use them).
    train: TrainConfig = TrainConfig(steps=20000, batch_size=64, log_every=50, ckpt_every=1000, ema_decay=0.999,
                                     ema_warmup=True, optim=OptimConfig(warmup_steps=500))
    data: DataConfig = field(default_factory=DataConfig)


def make_config(preset: str, data: str, encoder: str, overrides: Sequence[str] = ()) -> DiffusionRunConfig:
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose from {', '.join(PRESETS)}")
    cfg = DiffusionRunConfig(preset=preset, model=PRESETS[preset],
                             data=DataConfig(path=str(Path(data).absolute()), encoder=str(Path(encoder).absolute())))
    return apply_overrides(cfg, overrides)


# ------------------------------------------------------------------------------------------------
# Dotted overrides


def _parse_value(text: str, kind: Any, key: str):
    if kind is bool:
        low = text.strip().lower()
        if low in ("1", "true", "yes", "on"):
            return True
        if low in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"--set {key}: expected a boolean (true/false), got {text!r}")
    if kind is int:
        try:
            f = float(text.replace("_", ""))
        except ValueError:
            raise ValueError(f"--set {key}: expected an integer, got {text!r}") from None
        if f != int(f):
            raise ValueError(f"--set {key}: expected an integer, got {text!r}")
        return int(f)
    if kind is float:
        try:
            return float(text.replace("_", ""))
        except ValueError:
            raise ValueError(f"--set {key}: expected a number, got {text!r}") from None
    if kind is str:
        return text
    raise ValueError(f"--set {key}: values of type {kind} cannot be set from the command line")


def _set_path(obj, path: list[str], text: str, full: str):
    hints = typing.get_type_hints(type(obj))
    names = [f.name for f in dataclasses.fields(obj)]
    name = path[0]
    if name not in names:
        close = difflib.get_close_matches(name, names, n=1)
        hint = f" (did you mean {'.'.join(full.split('=')[0].split('.')[:-len(path)] + [close[0]])!r}?)" if close else ""
        raise ValueError(f"--set {full}: unknown key {name!r}{hint}; valid keys here: {', '.join(names)}")
    cur = getattr(obj, name)
    if dataclasses.is_dataclass(cur):
        if len(path) == 1:
            sub = ", ".join(f"{name}.{f.name}" for f in dataclasses.fields(cur))
            raise ValueError(f"--set {full}: {name!r} is a group; set one of its keys: {sub}")
        return dataclasses.replace(obj, **{name: _set_path(cur, path[1:], text, full)})
    if len(path) > 1:
        raise ValueError(f"--set {full}: {name!r} is a value, not a group")
    return dataclasses.replace(obj, **{name: _parse_value(text, hints[name], full.split("=")[0])})


def apply_overrides(cfg, overrides: Sequence[str]):
    """Apply ``key.sub=value`` strings to a (nested) frozen dataclass, type-checked."""
    for item in overrides:
        if "=" not in item:
            raise ValueError(f"--set {item!r}: expected key=value (e.g. train.optim.lr=3e-4)")
        key, text = item.split("=", 1)
        cfg = _set_path(cfg, key.strip().split("."), text.strip(), item)
    if isinstance(cfg, DiffusionRunConfig):
        validate(cfg)
    return cfg


def validate(cfg: DiffusionRunConfig) -> None:
    m, d = cfg.model, cfg.diffusion
    if m.dim % m.heads:
        raise ValueError(f"model.dim {m.dim} is not divisible by model.heads {m.heads}")
    if cfg.data.sampling not in ("clips", "pairs"):
        raise ValueError(f"data.sampling must be 'clips' or 'pairs', got {cfg.data.sampling!r}")
    if not 0 < cfg.data.fraction <= 1:
        raise ValueError(f"data.fraction must be in (0, 1], got {cfg.data.fraction}")
    if not 0 <= d.p_soft <= d.p_hard <= 1:
        raise ValueError(f"need 0 <= diffusion.p_soft <= diffusion.p_hard <= 1, got {d.p_soft}, {d.p_hard}")


def config_from_dict(doc: dict) -> DiffusionRunConfig:
    """Rebuild the run config from a run folder's config.json."""
    def build(cls, d):
        kw = {}
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if f.name in d:
                kw[f.name] = build(hints[f.name], d[f.name]) if dataclasses.is_dataclass(hints[f.name]) else d[f.name]
        return cls(**kw)

    model = {k: v for k, v in doc["model"].items() if k in {f.name for f in dataclasses.fields(DiTConfig)}}
    return DiffusionRunConfig(preset=doc["preset"], model=build(DiTConfig, model),
                              diffusion=build(D.DiffusionConfig, doc["diffusion"]),
                              train=build(TrainConfig, doc["train"]), data=build(DataConfig, doc["data"]))


# ------------------------------------------------------------------------------------------------
# Model accounting


def params_non_embedding(cfg: DiTConfig) -> int:
    """Trainable parameters without the learned token embeddings (3 CLS + the null text): what
    scaling fits use. The sinusoidal PE table is not a parameter."""
    return param_count(cfg) - (3 + 1) * cfg.dim


def make_model(cfg: DiTConfig, bf16: bool = False) -> TrebleDenoiser:
    return TrebleDenoiser(cfg, dtype=jnp.bfloat16 if bf16 else jnp.float32)


# ------------------------------------------------------------------------------------------------
# Data


@dataclass
class TrainData:
    """The training items in memory: normalised motion per clip + text lookups from the cache."""

    clips: np.ndarray  # dataset clip indices (train split, fraction)
    levels: int
    x_NxFx42x4: np.ndarray  # normalised diffusion features of ``clips``
    cache: Any  # TextCache
    norm: Any  # NormStats
    items: np.ndarray | None = None  # data.sampling="pairs": the chosen item ids (clip position × levels + level)

    @property
    def num_items(self) -> int:
        return len(self.clips) * self.levels if self.items is None else len(self.items)

    def batch(self, idx: np.ndarray) -> dict:
        idx = np.asarray(idx) if self.items is None else self.items[np.asarray(idx)]
        ci, lv = idx // self.levels, idx % self.levels
        clip = self.clips[ci]
        hs, ms = zip(*(self.cache.lookup(clip, f, lv) for f in FIELDS))
        return {"x0": self.x_NxFx42x4[ci], "text": np.stack(hs, 1), "mask": np.stack(ms, 1)}


def load_train_data(cfg: DiffusionRunConfig) -> TrainData:
    from handx_jax import representation as rep
    from handx_jax.data.dataset import Dataset
    from handx_jax.text.cache import open_cache

    ds = Dataset.open(cfg.data.path)
    cache = open_cache(cfg.data.path, cfg.data.encoder, max_len=cfg.data.text_max_len, dtype=cfg.data.cache_dtype)
    pairs = cfg.data.sampling == "pairs"
    clips = np.asarray(ds.split("train", 1.0 if pairs else cfg.data.fraction))
    if not len(clips):
        raise DataError("the train split is empty", path=cfg.data.path)
    norm = rep.NormStats.from_npz_dict(ds.stats, "diffusion")
    xs = [norm.normalize(rep.to_diffusion(np.asarray(ds.motion[clips[s:s + 1024]], np.float64)))
          for s in range(0, len(clips), 1024)]
    x = np.concatenate(xs).astype(np.float32)
    levels = int(ds.meta["levels"])
    items = None
    if pairs:  # reference §1.2: np.random.seed(42); np.random.choice(n_items, k, replace=False)
        n = len(clips) * levels
        items = np.sort(np.random.RandomState(42).permutation(n)[:max(1, round(cfg.data.fraction * n))])
    return TrainData(clips=clips, levels=levels, x_NxFx42x4=x, cache=cache, norm=norm, items=items)


# ------------------------------------------------------------------------------------------------
# Training


def make_loss(model: TrebleDenoiser, dcfg: D.DiffusionConfig):
    sched = D.cosine_schedule(dcfg.steps)

    def loss(params, batch, rng, train: bool):
        k_t, k_n, k_drop, k_do = jax.random.split(rng, 4)
        x0 = batch["x0"]
        B = x0.shape[0]
        t = jax.random.randint(k_t, (B,), 0, sched.T)  # uniform t (reference §3.4)
        x_t = D.q_sample(sched, x0, t, jax.random.normal(k_n, x0.shape))
        # Per-branch (reference §3.2) and joint (all three, for guidance) conditioning dropout.
        drop = D.cond_drop_mask(k_drop, B, dcfg) if train else jnp.zeros((B, 3), bool)
        x0_hat = model.apply(params, x_t, t, jnp.swapaxes(batch["text"], 0, 1), jnp.swapaxes(batch["mask"], 0, 1),
                             drop, deterministic=not train, rngs={"dropout": k_do})
        return D.diffusion_loss(x0, x0_hat, dcfg)

    return loss


def run_record(cfg: DiffusionRunConfig, cache_meta: dict) -> dict:
    """config.json content (besides ``train``, which the loop adds)."""
    mean_len = float(cache_meta["mean_tokens"])
    fwd = forward_flops(cfg.model, max(1, round(mean_len)))
    return {
        "family": FAMILY, "preset": cfg.preset,
        "model": dataclasses.asdict(cfg.model),
        "diffusion": dataclasses.asdict(cfg.diffusion),
        "data": dataclasses.asdict(cfg.data),
        "data_fraction": cfg.data.fraction,
        "params": param_count(cfg.model),
        "params_non_embedding": params_non_embedding(cfg.model),
        # Forward FLOPs of the denoiser for one sample at the cache's mean caption length; the step
        # itself runs at the cache's padded length (flops_per_sample_padded).
        "flops_per_sample": fwd,
        "flops_per_sample_padded": forward_flops(cfg.model, int(cache_meta["Lmax"])),
        "text_len_mean": mean_len,
        "text_flops_per_sample": 3 * float(cache_meta["encoder_flops_per_caption"]["mean"]),
        "text_cache": {"fingerprint": cache_meta["fingerprint"], "encoder_fingerprint": cache_meta["encoder_fingerprint"],
                       "Lmax": cache_meta["Lmax"], "d_model": cache_meta["d_model"]},
    }


def _check_resume(run_dir: Path, record: dict, cfg: DiffusionRunConfig) -> None:
    """Re-running on an existing run folder resumes it, but only with the same configuration."""
    p = run_dir / "config.json"
    if not p.exists():
        return
    old = json.loads(p.read_text())
    new = {**record, "train": dataclasses.asdict(cfg.train)}
    diff = [k for k in ("model", "diffusion", "data", "train")
            if json.loads(json.dumps(old.get(k))) != json.loads(json.dumps(new[k]))]
    if diff:
        raise DataError(f"run folder exists with a different configuration ({', '.join(diff)} differ); "
                        "use a new --out to start another run", path=run_dir)


def train_diffusion(run_dir: str | os.PathLike, cfg: DiffusionRunConfig, *, stop_at: int | None = None,
                    on_log=None) -> dict:
    """Train (or resume) a diffusion run in ``run_dir``; returns the train loop's result."""
    from handx_jax.train import train

    validate(cfg)
    run_dir = Path(run_dir)
    data = load_train_data(cfg)
    D_text = int(data.cache.meta["d_model"])
    if cfg.model.text_dim != D_text:
        cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, text_dim=D_text))
    record = run_record(cfg, data.cache.meta)
    _check_resume(run_dir, record, cfg)
    run_dir.mkdir(parents=True, exist_ok=True)
    if jax.process_index() == 0:
        np.savez(run_dir / NORM_FILE, **data.norm.to_npz_dict("diffusion"))
    model = make_model(cfg.model, cfg.train.bf16)
    L = int(data.cache.meta["Lmax"])

    def init(rng):
        return init_denoiser(cfg.model, rng, text_len=L)[1]

    return train(run_dir, init=init, loss=make_loss(model, cfg.diffusion), get_batch=data.batch,
                 num_examples=data.num_items, cfg=cfg.train, config=record, stop_at=stop_at, on_log=on_log,
                 flops_per_sample=record["flops_per_sample"])


# ------------------------------------------------------------------------------------------------
# Loading a trained run


@dataclass
class DiffusionRun:
    """A trained run, ready to sample: model, (EMA) params, configs, normalisation, text encoder."""

    run_dir: Path
    cfg: DiffusionRunConfig
    model: TrebleDenoiser
    params: Any
    step: int
    norm: Any
    encoder: Any
    used_ema: bool

    def encode(self, texts: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """Hidden states (N, L, D) float32 and mask (N, L) bool, at the run's text max_len."""
        e, h = self.encoder.encode(list(texts), max_len=self.cfg.data.text_max_len)
        m = e.mask_BxL.astype(bool)
        # Rounded through the cache dtype, so prompts look exactly like the training text.
        return (h * m[..., None]).astype(self.cfg.data.cache_dtype).astype(np.float32), m


def load_run(run_dir: str | os.PathLike, *, ema: bool = True, encoder: str | None = None,
             overrides: Sequence[str] = ()) -> DiffusionRun:
    """Open a run folder for generation. ``overrides`` may change ``diffusion.*`` (guidance, masks)."""
    from handx_jax import representation as rep
    from handx_jax.text.t5 import load_hf_t5_encoder
    from handx_jax.train import load_params

    run_dir = Path(run_dir)
    doc = json.loads((run_dir / "config.json").read_text()) if (run_dir / "config.json").exists() else None
    if doc is None or doc.get("family") != FAMILY:
        raise DataError("not a diffusion run folder (config.json missing or family is not 'diffusion')", path=run_dir)
    cfg = config_from_dict(doc)
    bad = [o for o in overrides if not o.split("=", 1)[0].strip().startswith("diffusion.")]
    if bad:
        raise ValueError(f"generation can only override diffusion.* keys, got {bad}")
    cfg = apply_overrides(cfg, overrides)
    enc = load_hf_t5_encoder(encoder or cfg.data.encoder)
    want = doc.get("text_cache", {}).get("encoder_fingerprint")
    if want and enc.fingerprint != want:
        raise DataError(f"encoder fingerprint {enc.fingerprint} differs from the one the run was trained with "
                        f"({want})", path=encoder or cfg.data.encoder)
    params, step = load_params(run_dir, ema=ema)
    with np.load(run_dir / NORM_FILE) as z:
        norm = rep.NormStats.from_npz_dict(dict(z), "diffusion")
    used_ema = bool(ema and cfg.train.ema_decay > 0)
    return DiffusionRun(run_dir, cfg, make_model(cfg.model), params, step, norm, enc, used_ema)
