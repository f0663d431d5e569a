"""The diffusion family: run config, training glue, and loading a trained run for sampling.

A run is ``DiffusionRunConfig`` = preset-derived ``DiTConfig`` + ``DiffusionConfig`` + ``TrainConfig``
+ ``DataConfig``, changed with dotted ``--set key=value`` overrides (type-checked; unknown keys are an
error with a suggestion). Training items are (clip, level) pairs of the train split's nested data
fraction; item j of a clip uses annotation level j for all three texts, as the reference loader does
(reference §1.2). The normalised diffusion representation of every training clip is computed once and
held in memory; text comes from the frozen-encoder cache (the encoder never runs in the step). Each
branch's text is dropped to the null embedding independently with p = ``cond_drop`` (§3.2), and all
three at once with p = ``joint_drop`` (``diffusion.cond_drop_mask``); t is uniform; the loss is the x0
objective of §3.5.

The run folder follows ``analysis.schema``'s contract: ``config.json`` holds ``family``, the model
axes (under ``model``), ``data_fraction``, ``params``, ``params_non_embedding``, ``flops_per_sample``
and ``text_flops_per_sample``; ``metrics.jsonl`` logs the cumulative ``train_flops``. The run also
keeps ``norm_stats.npz`` so generation does not need the dataset.

One concern: the diffusion family's side of the registry contract (its config and presets, training,
loading, generation and command-line hooks, ``families/__init__.py``), in the one module the registry
names; the Gaussian process is ``process.py``'s, the compiled sampler ``sampling.py``'s.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.families.diffusion import process as D
from handx_jax.config import ConfigError, apply_overrides, from_dict, get_preset, to_dict
from handx_jax.families import entry, generation_config, run_config
from handx_jax.infra.errors import DataError
from handx_jax.models.dit import PRESETS, DiTConfig, TrebleDenoiser, forward_flops, init_denoiser, param_count, size_name
from handx_jax.optim import OptimConfig
from handx_jax.train import TrainConfig

FAMILY = "diffusion"
NORM = entry(FAMILY).norm_preset().name  # the stats.npz prefix its registry entry declares
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
class SampleConfig:
    """Generation settings of the run: its defaults for ``handx generate`` and a sweep's generate stage,
    changed like any other key (``--set sample.steps=25``; ``handx generate --sampler/--sample-steps`` are the
    same keys). The guidance scale is ``diffusion.guidance``."""

    sampler: str = "ddpm"  # "ddpm" (ancestral, all T steps, the reference) or "ddim"
    steps: int = 50  # DDIM steps (DDPM always takes all diffusion.steps)
    # Contact guidance at sampling time (handx_jax/families/diffusion/guidance.py, issue 33): "" = off (the default);
    # "caption" = the contact events of each prompt's record; or a written list such as
    # "L.thumb-R.thumb@20:40,L.index-R.palm". Strength s scales BimArt's unit step (§3.5: λ_c = 1/‖∇‖);
    # the schedule w(t) is "late" (√ᾱ_t) or "constant". s = 16 realised 59% of the captions' inter-hand
    # contacts on make demo's run (s = 1: 5%; s = 4: 35%), at twice the penetration (docs/results/guidance).
    contact: str = ""
    contact_strength: float = 16.0
    contact_schedule: str = "late"


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
    sample: SampleConfig = SampleConfig()

    def validate(self) -> None:
        m, d = self.model, self.diffusion
        if m.dim % m.heads:
            raise ConfigError(f"model.dim {m.dim} is not divisible by model.heads {m.heads}")
        if self.data.sampling not in ("clips", "pairs"):
            raise ConfigError(f"data.sampling must be 'clips' or 'pairs', got {self.data.sampling!r}")
        if not 0 < self.data.fraction <= 1:
            raise ConfigError(f"data.fraction must be in (0, 1], got {self.data.fraction}")
        if not 0 <= d.p_soft <= d.p_hard <= 1:
            raise ConfigError(f"need 0 <= diffusion.p_soft <= diffusion.p_hard <= 1, got {d.p_soft}, {d.p_hard}")
        if self.sample.sampler not in ("ddpm", "ddim"):
            raise ConfigError(f"sample.sampler must be 'ddpm' or 'ddim', got {self.sample.sampler!r}")
        if self.sample.steps < 1:
            raise ConfigError(f"sample.steps must be at least 1, got {self.sample.steps}")
        from handx_jax.families.diffusion import guidance

        c = self.sample.contact.strip()
        if c and c != guidance.CAPTION:
            try:
                guidance.parse_contacts(c)
            except ValueError as e:
                raise ConfigError(f"sample.contact: {e}") from None
        if self.sample.contact_schedule not in guidance.SCHEDULES:
            raise ConfigError(f"sample.contact_schedule must be one of {', '.join(guidance.SCHEDULES)}, got "
                              f"{self.sample.contact_schedule!r}")
        if not self.sample.contact_strength >= 0:
            raise ConfigError(f"sample.contact_strength must be >= 0, got {self.sample.contact_strength}")


Config = DiffusionRunConfig


def validate(cfg: DiffusionRunConfig) -> None:
    cfg.validate()


def make_config(preset: str = "tiny", overrides: Sequence[str] = (), *, data: str = "", encoder: str = ""
                ) -> DiffusionRunConfig:
    """The run config of a named size with dotted overrides. The recorded ``preset`` is the size the
    run really has: if overrides change the model's layers/dim/heads/ff, it becomes the ladder name
    of that size (e.g. ``L12-d768``) or a derived one (``L6-d320-H5-F1280``)."""
    model = get_preset(PRESETS, preset)
    cfg = DiffusionRunConfig(preset=preset, model=model,
                             data=DataConfig(path=str(Path(data).absolute()) if data else "",
                                             encoder=str(Path(encoder).absolute()) if encoder else ""))
    cfg = apply_overrides(cfg, overrides)
    return dataclasses.replace(cfg, preset=size_name(cfg.model, preset))


def config_from_dict(doc: dict) -> DiffusionRunConfig:
    """Rebuild the run config from a run folder's config.json."""
    return from_dict(DiffusionRunConfig, doc)


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
    from handx_jax.dataset.format import Dataset
    from handx_jax.text.cache import open_cache

    ds = Dataset.open(cfg.data.path)
    cache = open_cache(cfg.data.path, cfg.data.encoder, max_len=cfg.data.text_max_len, dtype=cfg.data.cache_dtype)
    pairs = cfg.data.sampling == "pairs"
    clips = np.asarray(ds.split("train", 1.0 if pairs else cfg.data.fraction))
    if not len(clips):
        raise DataError("the train split is empty", path=cfg.data.path)
    norm = rep.NormStats.from_npz_dict(ds.stats, NORM, path=ds.root / "stats.npz")
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


def make_loss(model: TrebleDenoiser, dcfg: D.DiffusionConfig, norm=None):
    """The x0 objective (reference §3.5). With ``dcfg.observe_prob`` > 0 (``norm``: the run's
    normalisation, for re-centring) some items see their first frames clean (``D.observation_frames``)."""
    sched = D.cosine_schedule(dcfg.steps)
    observe = dcfg.observe_prob > 0
    if observe:
        mean = jnp.asarray(norm.mean, jnp.float32)
        scale = jnp.asarray(norm.std + np.float32(norm.eps), jnp.float32)

    def loss(params, batch, rng, train: bool):
        k_t, k_n, k_drop, k_do = jax.random.split(rng, 4)  # as before the option existed: same draws when off
        x0 = batch["x0"]
        B = x0.shape[0]
        t = jax.random.randint(k_t, (B,), 0, sched.T)  # uniform t (reference §3.4)
        if observe:  # the clip centred on its observation, as the prediction task places it
            obs_BxF = D.observation_frames(jax.random.fold_in(rng, 4), B, x0.shape[1], dcfg)
            x0 = D.centre_on_observed(x0, obs_BxF, mean, scale)
        anchor = D.held_anchor(x0, obs_BxF) if observe and dcfg.observe_residual else 0.0  # 0 on observed frames
        x_t = D.q_sample(sched, x0 - anchor, t, jax.random.normal(k_n, x0.shape))
        if observe:  # the observed frames enter clean, as the sampler gives them (process.sample)
            x_t = jnp.where(obs_BxF[:, :, None, None], x0, x_t)
        # Per-branch (reference §3.2) and joint (all three, for guidance) conditioning dropout.
        drop = D.cond_drop_mask(k_drop, B, dcfg) if train else jnp.zeros((B, 3), bool)
        x0_hat = model.apply(params, x_t, t, jnp.swapaxes(batch["text"], 0, 1), jnp.swapaxes(batch["mask"], 0, 1),
                             drop, deterministic=not train, rngs={"dropout": k_do})
        return D.diffusion_loss(x0, x0_hat + anchor, dcfg)  # the output is the residual where anchor ≠ 0

    return loss


def run_record(cfg: DiffusionRunConfig, cache_meta: dict) -> dict:
    """config.json content (besides ``train``, which the loop adds)."""
    mean_len = float(cache_meta["mean_tokens"])
    fwd = forward_flops(cfg.model, max(1, round(mean_len)))
    return {
        "family": FAMILY, "preset": cfg.preset,
        "model": dataclasses.asdict(cfg.model),
        "diffusion": _diffusion_record(cfg.diffusion),
        "data": dataclasses.asdict(cfg.data),
        "sample": dataclasses.asdict(cfg.sample),
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


def _diffusion_record(dcfg: D.DiffusionConfig) -> dict:
    """config.json's ``diffusion``: without observation training (the default) the observe_* keys are left
    out, so a run's record, and resuming a folder written before they existed, are as before."""
    d = dataclasses.asdict(dcfg)
    if not dcfg.observe_prob:
        d.pop("observe_prob"), d.pop("observe_max"), d.pop("observe_residual")
    return d


# Run config keys a resumed run must share with the folder's config.json (train.py refuses others).
RESUME_KEYS = ("model", "diffusion", "data", "train")


def train(run_dir: str | os.PathLike, cfg: DiffusionRunConfig, *, stop_at: int | None = None, on_log=None,
          encoder=None) -> dict:
    """Train (or resume) a diffusion run in ``run_dir``; returns the train loop's result. The text
    comes from the cache, so ``encoder`` (a loaded FrozenEncoder) is not needed; it is accepted for
    the family interface."""
    from handx_jax import train as loop

    cfg.validate()
    run_dir = Path(run_dir)
    data = load_train_data(cfg)
    D_text = int(data.cache.meta["d_model"])
    if cfg.model.text_dim != D_text:
        cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, text_dim=D_text))
    record = run_record(cfg, data.cache.meta)
    loop.check_resume(run_dir, {**record, "train": to_dict(cfg.train)}, RESUME_KEYS)
    run_dir.mkdir(parents=True, exist_ok=True)
    if jax.process_index() == 0:
        np.savez(run_dir / NORM_FILE, **data.norm.to_npz_dict(NORM))
    model = make_model(cfg.model, cfg.train.bf16)
    L = int(data.cache.meta["Lmax"])

    def init(rng):
        return init_denoiser(cfg.model, rng, text_len=L)[1]

    return loop.train(run_dir, loop.TrainSpec(
        init=init, loss=make_loss(model, cfg.diffusion, data.norm), cfg=cfg.train, config=record, get_batch=data.batch,
        num_examples=data.num_items, flops_per_sample=record["flops_per_sample"], resume_keys=RESUME_KEYS),
        stop_at=stop_at, on_log=on_log)



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

    # The family interface's run object: what ``handx generate`` calls.
    @property
    def tasks(self) -> tuple[str, ...]:
        """The registry's tasks (the sampler's masks are D.TASKS); a run trained with an observation on every
        item (diffusion.observe_prob = 1) never learnt to start from nothing: prediction only."""
        if self.cfg.diffusion.observe_prob >= 1:
            return ("prediction",)
        return entry(FAMILY).tasks

    def generate(self, prompts, opts, *, samples: int = 1, task: str = "text2motion", sources=None,
                 keyframes: Sequence[int] = (30,), fixed_hand: str = "left") -> np.ndarray:
        """G samples per prompt: joints (P, G, F, 2, 21, 3); see ``sampling.generate``."""
        from handx_jax.families.diffusion import sampling

        return sampling.generate(self, prompts, opts, samples=samples, task=task, sources=sources,
                                   keyframes=keyframes, fixed_hand=fixed_hand)

    def generate_long(self, segments, opts, *, samples: int = 1, source=None) -> np.ndarray:
        """Chained segments (App. D.2): joints (G, T, 2, 21, 3); see ``sampling.generate_long``."""
        from handx_jax.families.diffusion import sampling

        return sampling.generate_long(self, segments, opts, samples=samples, source=source)

    def check_prompts(self, prompts) -> None:
        """Refuse a typed prompt longer than the text window (``text.prompts.check_window``); each field
        is encoded on its own. ``generate`` itself cuts at the window, as the text cache did in training."""
        from handx_jax.text.prompts import check_window

        check_window(self.encoder.tokenizer, prompts, self.cfg.data.text_max_len)

    def describe(self, opts) -> str:
        """How the samples were drawn, for the command's summary line."""
        g = self.cfg.diffusion.guidance if opts.guidance is None else opts.guidance
        sampler = f"{opts.sampler}-{opts.steps}" if opts.sampler == "ddim" else opts.sampler
        contact = (f", contact guidance {opts.contact!r} (strength {opts.contact_strength:g}, {opts.contact_schedule})"
                   if opts.contact.strip() else "")
        return f"{sampler}, guidance {g}{contact}, {'EMA' if self.used_ema else 'raw'} params at step {self.step}"


def load(run_dir: str | os.PathLike, *, ema: bool = True, encoder=None, overrides: Sequence[str] = ()) -> DiffusionRun:
    """Open a run folder for generation. ``encoder`` is a folder or an already loaded FrozenEncoder
    (default: the folder the run was trained with); ``overrides`` may change ``sample.*`` (sampler,
    steps) and ``diffusion.*`` (guidance, masks)."""
    from handx_jax import representation as rep
    from handx_jax.text.hf import as_encoder
    from handx_jax.train import load_params

    run_dir = Path(run_dir)
    doc = run_config(run_dir, FAMILY)
    cfg = generation_config(config_from_dict(doc), overrides, ("sample.", "diffusion."))
    enc = as_encoder(encoder or cfg.data.encoder)
    want = doc.get("text_cache", {}).get("encoder_fingerprint")
    if want and enc.fingerprint != want:
        raise DataError(f"encoder fingerprint {enc.fingerprint} differs from the one the run was trained with "
                        f"({want})", path=enc.path or cfg.data.encoder)
    params, step = load_params(run_dir, ema=ema)
    norm = rep.NormStats.read(run_dir / NORM_FILE, NORM)
    used_ema = bool(ema and cfg.train.ema_decay > 0)
    return DiffusionRun(run_dir, cfg, make_model(cfg.model), params, step, norm, enc, used_ema)



# ------------------------------------------------------------------------------------------------
# Accounting and the command-line hooks of the family interface (handx_jax.families)



def numbers(cfg: DiffusionRunConfig, *, text_len: int = 32, encoder_cfg=None) -> dict:
    """Parameters and analytic forward FLOPs per sample (2 per multiply-add; ``models.dit.forward_flops``)
    at ``text_len`` tokens per prompt; the frozen text encoder (``encoder_cfg``, default T5-base, the
    reference's encoder, §3.1) is counted apart, for three prompts."""
    from handx_jax.text.t5 import encoder_flops, t5_base

    enc_cfg = encoder_cfg if encoder_cfg is not None else t5_base()
    return {"params": param_count(cfg.model), "params_non_embedding": params_non_embedding(cfg.model),
            "flops_per_sample": forward_flops(cfg.model, text_len),
            "text_flops_per_sample": 3 * int(encoder_flops(enc_cfg, text_len))}


def add_train_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", required=True, help="dataset directory (with a text cache for --encoder)")
    p.add_argument("--encoder", required=True, help="frozen T5 encoder folder")


def config_from_args(args: argparse.Namespace) -> DiffusionRunConfig:
    return make_config(args.preset, args.set, data=args.data, encoder=args.encoder)


def add_params_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--layers", type=int, help="decoder layers (overrides the preset)")
    p.add_argument("--dim", type=int, help="model width")
    p.add_argument("--heads", type=int, help="attention heads")
    p.add_argument("--ff", type=int, help="feed-forward width")
    p.add_argument("--text-dim", type=int, default=768, help="text feature width (768 for T5-base)")
    p.add_argument("--text-len", type=int, default=32, help="tokens per prompt for the FLOPs count")
    p.add_argument("--encoder", help="encoder folder for text_flops_per_sample (default: T5-base)")
    p.add_argument("--convention", choices=("analytic", "paper"), default="analytic",
                   help="analytic: 2 FLOPs per multiply-add of every matmul, denoiser only (default); paper: also "
                        "print the multiply-adds of the Linear layers (as fvcore/thop count them) plus the frozen "
                        "T5-base encoder, which reproduces the paper's Table B FLOPs column "
                        "(handx_jax/families/diffusion/flops.py)")
    p.add_argument("--text-tokens", type=int, default=None,
                   help="paper convention: text tokens per branch the denoiser attends to (default 63, fitted to "
                        "Table B)")
    p.add_argument("--encoder-tokens", type=int, default=None,
                   help="paper convention: tokens through the T5 encoder per sample (default 40, fitted to Table B)")


def params_from_args(args: argparse.Namespace) -> tuple[str, dict]:
    """(a one-line description, ``numbers``) for ``handx params diffusion``."""
    sizes = [f"model.{k}={v}" for k, v in
             (("layers", args.layers), ("dim", args.dim), ("heads", args.heads), ("ff", args.ff),
              ("text_dim", args.text_dim)) if v is not None]
    cfg = make_config(args.preset, [*sizes, *args.set])
    enc_cfg = None
    if args.encoder:
        from handx_jax.text.hf import load_hf_t5_encoder

        enc_cfg = load_hf_t5_encoder(args.encoder).cfg
    m = cfg.model
    out = numbers(cfg, text_len=args.text_len, encoder_cfg=enc_cfg)
    label = (f"diffusion {cfg.preset}: L{m.layers} d{m.dim} H{m.heads} FF{m.ff} (text {m.text_dim}-d, "
             f"{args.text_len} tokens)")
    if args.convention == "paper":
        from handx_jax.families.diffusion import flops

        mem = flops.PAPER_MEM_TOKENS if args.text_tokens is None else args.text_tokens
        enc = flops.PAPER_ENCODER_TOKENS if args.encoder_tokens is None else args.encoder_tokens
        out = {**out, "convention": "paper", **flops.paper_flops(m, mem, enc, enc_cfg)}
        label += (f"; paper convention {out['flops_per_sample_paper'] / 1e9:.3f} G (Linear-layer MACs of the "
                  f"denoiser with {mem} text tokens per branch + the encoder on {enc} tokens)")
    return label, out


def add_generate_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sampler", choices=["ddpm", "ddim"], help="= --set sample.sampler=… (default: the run's, ddpm)")
    from handx_jax.cliargs import deprecated_flag

    deprecated_flag(p, "--steps", p.add_argument(
        "--sample-steps", type=int, help="= --set sample.steps=N: sampler steps of DDIM (DDPM always uses all T)"))
    p.add_argument("--guidance", type=float, help="= --set diffusion.guidance=X: CFG scale (default: the run's, 2.5)")
    p.add_argument("--contact", help="= --set sample.contact=SPEC: contact guidance (default off). 'caption' = the "
                                     "contact events of each prompt's record (prompts from a dataset), or a list "
                                     "'L.thumb-R.index@20:40,L.index-R.palm' (HAND.PART-HAND.PART[@START:END], "
                                     "PART thumb|index|middle|ring|pinky|palm|tips; frames half-open)")
    p.add_argument("--contact-strength", type=float, help="= --set sample.contact_strength=S: step scale (1 = "
                                                          "BimArt's unit step per denoising step; default 16)")
    p.add_argument("--contact-schedule", choices=["late", "constant"],
                   help="= --set sample.contact_schedule=…: strength over steps (late = sqrt(alpha_bar_t))")
    p.add_argument("--observed-frames", type=int, default=20,
                   help="--task prediction: observed frames, kept exactly, in (0, 60) (default 20)")


def load_for_generate(args: argparse.Namespace, *, ema: bool, encoder, seed: int, batch_size: int):
    """(run, sampling options) for ``handx generate``: the run's ``sample``/``diffusion`` settings, then
    ``--set`` overrides, then the flags (which name the same keys)."""
    from handx_jax.families.diffusion.sampling import SampleOptions
    from handx_jax.text.prompts import typed_prompts

    flags = [f"{k}={v}" for k, v in (("sample.sampler", args.sampler), ("sample.steps", args.sample_steps),
                                     ("diffusion.guidance", args.guidance), ("sample.contact", args.contact),
                                     ("sample.contact_strength", args.contact_strength),
                                     ("sample.contact_schedule", args.contact_schedule)) if v is not None]
    SampleOptions(observed_frames=args.observed_frames)  # its range check, before the run is read
    run = load(args.run, ema=ema, encoder=encoder, overrides=[*args.set, *flags])
    run.check_prompts(typed_prompts(args))
    s = run.cfg.sample
    return run, SampleOptions(sampler=s.sampler, steps=s.steps, seed=seed, batch_size=batch_size,
                              observed_frames=args.observed_frames, contact=s.contact,
                              contact_strength=s.contact_strength, contact_schedule=s.contact_schedule)
