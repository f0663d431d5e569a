"""The autoregressive family: a text-prefix LM over FSQ motion tokens (paper §5.2; reference §4.5–4.8).

    handx train tokenizer --data DIR --set model.codebook=4096 --out TOK   # one per (dataset, codebook)
    handx data tokens --tokenizer TOK --data DIR                    # token cache
    handx text cache --data DIR --encoder ENC --joined              # the joined-prompt text cache
    handx train ar --data DIR --encoder ENC --tokenizer TOK --preset 8L-512 --out RUN
    handx generate --run RUN --data DIR --split test --out gen.npz

One concern: the AR family's side of the registry contract (its config and presets, training, loading,
generation and command-line hooks, ``families/__init__.py``), in the one module the registry names;
decoding is ``decode.py``'s.

Training items are (clip, level) pairs of the train split's nested fraction. The prefix is the frozen
text features of the clip's three prompts at that level, joined with separators (the text cache's
joined mode); the same text mode is used at generation (the reference trains on the full prefix and
evaluates with the first token only, §4.5; that mismatch is not ported). The targets are the clip's
30 codes from the token cache, then END (§4.6). The LM's vocabulary is the tokenizer's REAL codebook
size (e.g. 4375 for "4096"); the run records both sizes and the tokenizer's provenance.

Generation decodes greedily by default (the paper), in one jitted loop with a KV cache
(``families.ar.decode``), then tokens → FSQ decoder → de-normalised 288-d → global joints. Tasks:
``text2motion`` and ``prediction`` (the first ``--observed-frames`` frames of ``--source`` are
encoded and prefilled; the rest is generated, and joined to the observed frames, which are returned as
given: :func:`stitch`).
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

from handx_jax.families.ar import decode as AD
from handx_jax.config import ConfigError, apply_overrides, from_dict, get_preset, to_dict
from handx_jax.families import tokenizer as T
from handx_jax.families import entry, generation_config, run_config
from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_json
from handx_jax.models import prefix_lm as P
from handx_jax.optim import OptimConfig
from handx_jax.train import TrainConfig

FAMILY = "ar"
PRESETS = P.PRESETS
TASKS = entry(FAMILY).tasks  # declared in the registry (families.FAMILIES)


@dataclass(frozen=True)
class DataConfig:
    path: str = ""  # dataset directory (with a joined text cache and a token cache)
    encoder: str = ""  # frozen T5 encoder folder
    tokenizer: str = ""  # tokenizer run folder (its token cache must exist in the dataset)
    fraction: float = 1.0
    text_max_len: int = 128  # the joined text cache's max_len
    cache_dtype: str = "float16"
    # Conditioning dropout: each training item's prefix is replaced by the null prefix
    # (decode.null_prefix) with this probability, so that the LM also learns l_u, the unconditional
    # logits classifier-free guidance (sample.guidance) extrapolates from. 0 = off (the reference: §4.6).
    text_drop: float = 0.0
    # Caption levels the training items use (0 = most concise; empty = all, the reference). The standard
    # evaluator scores at level 0. On the 1,200-clip prefix, tiny LMs trained on all five levels kept a
    # held-out text gap near 0 for hundreds of steps, one trained on level 0 alone did not (docs/results/ar_text).
    levels: tuple[int, ...] = ()


@dataclass(frozen=True)
class SampleConfig:
    """Decoding defaults of the run (``handx generate`` flags override them)."""

    temperature: float = 0.0  # greedy, the paper's default
    top_k: int = 0
    top_p: float = 1.0
    guidance: float = 1.0  # classifier-free guidance on the logits (decode.DecodeOptions); 1 = off


# Reference §4.7: batch 128, AdamW(3e-4, (0.9, 0.999), wd 1e-6, eps 1e-6), 10% linear warm-up then
# cosine to 0. Weight decay here skips vectors (norm gains), as the shared loop does for all families.
REFERENCE_TRAIN = TrainConfig(steps=150000, batch_size=128, log_every=100, ckpt_every=10000,
                              optim=OptimConfig(lr=3e-4, b1=0.9, b2=0.999, eps=1e-6, weight_decay=1e-6,
                                                warmup_steps=15000, schedule="cosine", grad_clip=1.0))
# The CPU sizes' recipe (tiny, small): minutes on 2 cores, and something learnt at the tiny sweep's 300
# steps: the reference's 15,000-step warm-up at 3e-4 would leave such a run near its initial loss.
# Host memory is set by XLA's temporary buffer of one step, which the glibc heap (handx_jax.infra.hostmem)
# holds two or three times over: for `small` on the joined prefix (128 text + 31 motion slots) it was
# 1,069 MB at batch 64, most of it attention weights and SwiGLU intermediates kept for the backward
# pass. The LM's own backward passes (models.prefix_lm.attend, swiglu) bring it to 713 MB, and `small`
# computes its batch of 64 as two microbatches of 32 (train.microbatch; 356 MB each): `handx train ar
# --preset small` on the 1,200-clip prefix peaked at 3.96 GB before, 1.42 GB after over 20 steps and
# 1.81 GB over 60 (the heap still grows by a buffer now and then; docs/results/ar_memory).
CPU_TRAIN = dataclasses.replace(REFERENCE_TRAIN, steps=2000, batch_size=64, log_every=50, ckpt_every=1000,
                                eval_every=500,
                                optim=dataclasses.replace(REFERENCE_TRAIN.optim, lr=1e-3, warmup_steps=100))
TRAIN_PRESETS = {name: CPU_TRAIN if name in ("tiny", "small") else REFERENCE_TRAIN for name in PRESETS}
TRAIN_PRESETS["small"] = dataclasses.replace(CPU_TRAIN, microbatch=32)


@dataclass(frozen=True)
class ARRunConfig:
    preset: str = "tiny"
    model: P.LMConfig = PRESETS["tiny"]
    train: TrainConfig = CPU_TRAIN  # the preset's recipe (TRAIN_PRESETS)
    data: DataConfig = field(default_factory=DataConfig)
    sample: SampleConfig = SampleConfig()

    def validate(self) -> None:
        m = self.model
        if m.dim % m.heads or (m.dim // m.heads) % 2:
            raise ConfigError(f"model.dim {m.dim} / model.heads {m.heads} must be an even integer (RoPE pairs)")
        if not 0 < self.data.fraction <= 1:
            raise ConfigError(f"data.fraction must be in (0, 1], got {self.data.fraction}")
        if not 0 <= self.data.text_drop < 1:
            raise ConfigError(f"data.text_drop must be in [0, 1), got {self.data.text_drop}")
        if len(set(self.data.levels)) != len(self.data.levels) or any(v < 0 for v in self.data.levels):
            raise ConfigError(f"data.levels must be distinct caption levels >= 0, got {list(self.data.levels)}")
        try:  # the decoding options' own range checks (decode.DecodeOptions)
            AD.DecodeOptions(self.sample.temperature, self.sample.top_k, self.sample.top_p, self.sample.guidance)
        except ValueError as e:
            raise ConfigError(f"sample.{e}") from None


Config = ARRunConfig


def _abs(p: str) -> str:
    return str(Path(p).absolute()) if p else ""


def make_config(preset: str = "tiny", overrides: Sequence[str] = (), *, data: str = "", encoder: str = "",
                tokenizer: str = "") -> ARRunConfig:
    """The run config of a named size; ``model.nb_code`` is taken from the tokenizer run when given."""
    model = get_preset(PRESETS, preset, "LM preset")
    if tokenizer:
        model = dataclasses.replace(model, nb_code=_tokenizer_record(tokenizer)["nb_code"])
    cfg = ARRunConfig(preset=preset, model=model, train=TRAIN_PRESETS[preset],
                      data=DataConfig(path=_abs(data), encoder=_abs(encoder), tokenizer=_abs(tokenizer)))
    return apply_overrides(cfg, overrides)


def _tokenizer_record(tokenizer_dir) -> dict:
    p = Path(tokenizer_dir) / "config.json"
    if not p.exists():
        raise DataError("not a tokenizer run folder (no config.json)", path=tokenizer_dir)
    doc = read_json(p, expect=dict)
    if doc.get("family") != T.FAMILY:
        raise DataError(f"run folder is a {doc.get('family')!r} run, not a tokenizer", path=tokenizer_dir)
    return doc


def numbers(cfg: ARRunConfig, *, text_len: int = 96, encoder_cfg=None) -> dict:
    """Params from shapes; analytic forward FLOPs per sample with a prefix of ``text_len`` joined-text
    tokens and 31 motion slots (30 codes + END); the frozen encoder over the joined text, apart."""
    from handx_jax.text.t5 import encoder_flops, t5_base

    enc_cfg = encoder_cfg if encoder_cfg is not None else t5_base()
    return {**P.param_counts(cfg.model), "flops_per_sample": P.forward_flops(cfg.model, text_len),
            "text_flops_per_sample": int(encoder_flops(enc_cfg, text_len))}


# ------------------------------------------------------------------------------------------------
# Data and training


@dataclass
class TrainData:
    clips: np.ndarray
    levels: int
    codes: np.ndarray  # (N_all, 30) token cache, dataset clip order
    cache: Any  # joined TextCache
    level_ids: tuple[int, ...] = ()  # data.levels: the caption levels items use (empty: 0..levels-1)

    @property
    def used_levels(self) -> np.ndarray:
        return np.asarray(self.level_ids or range(self.levels))

    @property
    def num_items(self) -> int:
        return len(self.clips) * len(self.used_levels)

    def batch(self, idx: np.ndarray) -> dict:
        n = len(self.used_levels)
        ci, lv = np.asarray(idx) // n, self.used_levels[np.asarray(idx) % n]
        clip = self.clips[ci]
        h, m = self.cache.lookup(clip, "joined", lv)
        return {"codes": self.codes[clip].astype(np.int32), "text": h, "mask": m}


def load_train_data(cfg: ARRunConfig):
    from handx_jax.dataset.format import Dataset
    from handx_jax.text.cache import open_cache

    for key in ("path", "encoder", "tokenizer"):
        if not getattr(cfg.data, key):
            raise ConfigError(f"data.{key} is empty: give --data, --encoder and --tokenizer")
    ds = Dataset.open(cfg.data.path)
    cache = open_cache(cfg.data.path, cfg.data.encoder, max_len=cfg.data.text_max_len, dtype=cfg.data.cache_dtype,
                       joined=True)
    tokens = T.open_token_cache(cfg.data.path, cfg.data.tokenizer)
    clips = np.asarray(ds.split("train", cfg.data.fraction))
    if not len(clips):
        raise DataError("the train split is empty", path=cfg.data.path)
    levels = int(ds.meta["levels"])
    if any(v >= levels for v in cfg.data.levels):
        raise ConfigError(f"data.levels {list(cfg.data.levels)}: the dataset has caption levels 0..{levels - 1}")
    return TrainData(clips, levels, tokens.codes, cache, tuple(cfg.data.levels)), tokens


RESUME_KEYS = ("model", "data", "train", "tokenizer")


def run_record(cfg: ARRunConfig, cache_meta: dict, tokens) -> dict:
    mean_len = max(1, round(float(cache_meta["mean_tokens"])))
    from handx_jax.text.t5 import T5Config

    enc_cfg = T5Config(**{k: v for k, v in cache_meta["encoder_config"].items()
                          if k in {f.name for f in dataclasses.fields(T5Config)}})
    n = numbers(cfg, text_len=mean_len, encoder_cfg=enc_cfg)
    tm = tokens.meta
    return {
        "family": FAMILY, "preset": cfg.preset, "model": to_dict(cfg.model), "data": to_dict(cfg.data),
        "sample": to_dict(cfg.sample), "data_fraction": cfg.data.fraction, **n,
        "flops_per_sample_padded": P.forward_flops(cfg.model, int(cache_meta["Lmax"])),
        "text_len_mean": float(cache_meta["mean_tokens"]),
        "codebook": tm["codebook"], "nb_code": tm["nb_code"],
        "tokenizer": {k: tm[k] for k in ("tokenizer_path", "tokenizer_fingerprint", "tokenizer_step", "codebook",
                                         "nb_code", "levels", "quantizer")} | {"token_cache": tm["fingerprint"]},
        "text_cache": {"fingerprint": cache_meta["fingerprint"], "encoder_fingerprint": cache_meta["encoder_fingerprint"],
                       "Lmax": cache_meta["Lmax"], "d_model": cache_meta["d_model"], "fields": "joined"},
    }


def make_loss(model: P.PrefixLM, text_drop: float = 0.0):
    def loss(params, batch, rng, train: bool):
        text, mask = batch["text"].astype(jnp.float32), batch["mask"]
        if train and text_drop > 0:  # data.text_drop: the item sees the null prefix (CFG's l_u)
            drop_B = jax.random.bernoulli(rng, text_drop, (mask.shape[0],))
            null_text, null_mask = AD.null_prefix(text, mask)
            text = jnp.where(drop_B[:, None, None], null_text, text)
            mask = jnp.where(drop_B[:, None], null_mask, mask)
        return P.lm_loss(model, params, text, mask, batch["codes"])

    return loss


EVAL_ITEMS = 1024  # held-out (clip, level) pairs scored by the evaluation hook


def other_text_items(items: np.ndarray, n_clips: int, levels: int) -> np.ndarray:
    """Item ids whose text is the NEXT held-out clip's at the same level (cyclic): the control of the text gap."""
    items = np.asarray(items)
    return ((items // levels + 1) % n_clips) * levels + items % levels


def make_evaluate(model: P.PrefixLM, data: TrainData, val_clips: np.ndarray, batch_size: int = 128):
    """Held-out token NLL (nats per motion slot: 30 codes + END, §4.6) and next-token accuracy on the first
    EVAL_ITEMS (clip, level) pairs of the val split, every ``eval_every`` steps and at the end; and
    ``eval/nll_other_text``, the same codes after another held-out clip's text (``other_text_items``), whose
    excess over ``eval/nll`` (``eval/text_gap``) is how much the LM uses its text: 0 for an LM that ignores it
    (docs/results/ar_text)."""
    held = dataclasses.replace(data, clips=np.asarray(val_clips))
    items = np.arange(min(held.num_items, EVAL_ITEMS))
    other = other_text_items(items, len(held.clips), len(held.used_levels))
    step = jax.jit(lambda p, b: P.lm_loss(model, p, b["text"].astype(jnp.float32), b["mask"], b["codes"]))

    def evaluate(params, ema, done):
        nll = acc = nll_o = 0.0
        for s in range(0, len(items), batch_size):
            idx = items[s:s + batch_size]
            b = held.batch(idx)
            l, aux = step(params, b)
            lo, _ = step(params, {**held.batch(other[s:s + batch_size]), "codes": b["codes"]})
            nll, acc, nll_o = nll + float(l) * len(idx), acc + float(aux["acc"]) * len(idx), nll_o + float(lo) * len(idx)
        n = len(items)
        return {"eval/nll": nll / n, "eval/acc": acc / n, "eval/nll_other_text": nll_o / n,
                "eval/text_gap": (nll_o - nll) / n}

    return evaluate


def train(run_dir: str | os.PathLike, cfg: ARRunConfig, *, stop_at: int | None = None, on_log=None,
          encoder=None) -> dict:
    """Train (or resume) an LM run from the token cache and the joined text cache; the evaluation hook logs
    the held-out token NLL on the val split (``make_evaluate``)."""
    from handx_jax.dataset.format import Dataset
    from handx_jax import train as loop

    cfg.validate()
    data, tokens = load_train_data(cfg)
    nb, D_text = int(tokens.meta["nb_code"]), int(data.cache.meta["d_model"])
    if cfg.model.nb_code != nb or cfg.model.text_dim != D_text:  # the vocabulary and text width follow the data
        cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, nb_code=nb, text_dim=D_text))
    record = run_record(cfg, data.cache.meta, tokens)
    run_dir = Path(run_dir)
    loop.check_resume(run_dir, {**record, "train": to_dict(cfg.train)}, RESUME_KEYS)
    model = P.PrefixLM(cfg.model)
    L = int(data.cache.meta["Lmax"])
    val = np.asarray(Dataset.open(cfg.data.path).split("val"))
    return loop.train(run_dir, loop.TrainSpec(
        init=lambda rng: P.init_lm(cfg.model, rng, text_len=L)[1], loss=make_loss(model, cfg.data.text_drop),
        cfg=cfg.train, config=record, get_batch=data.batch, num_examples=data.num_items,
        evaluate=make_evaluate(model, data, val) if len(val) else None,
        flops_per_sample=record["flops_per_sample"], resume_keys=RESUME_KEYS), stop_at=stop_at, on_log=on_log)


# ------------------------------------------------------------------------------------------------
# Loading and generation


@dataclass(frozen=True)
class GenerateOptions:
    decode: AD.DecodeOptions = AD.DecodeOptions()
    seed: int = 0
    batch_size: int = 256
    observed_frames: int = 20  # for the prediction task
    use_cache: bool = True
    # Prediction: frames over which the decoded continuation's hand pose is pulled onto the observed last
    # frame's (``stitch``); -1 = the rest of the clip, 0 = no pull (a jump at the boundary). With the
    # clip's own codes decoded (a perfect LM), MPJPE-RA over frames 17-60 of the 163 val clips of the
    # 4,000-clip prefix minus holding the last frame was -1.6 ± 1.7 mm at 8 frames, -5.6 ± 1.1 over the
    # rest of the clip (44): the tokenizer's pose error drifts slowly (docs/results/prediction/prefix4000).
    stitch_frames: int = -1

    def __post_init__(self) -> None:
        # The tokenizer codes 2 frames per token and at least one frame must be left to predict; checked
        # here, before a run or a source clip is read, for the CLI and the API alike.
        f = self.observed_frames
        if not (isinstance(f, int) and 0 < f < 60 and f % 2 == 0):
            raise ValueError(f"--observed-frames must be even and in (0, 60), got {f}")
        if not (isinstance(self.stitch_frames, int) and self.stitch_frames >= -1):
            raise ValueError(f"--stitch-frames must be a whole number >= -1 (-1: the rest of the clip), got "
                             f"{self.stitch_frames}")


def stitch(decoded_RxTx2x21x3: np.ndarray, source_RxTx2x21x3: np.ndarray, observed: int, frames: int) -> np.ndarray:
    """The prediction output: the source's own first ``observed`` frames, then the decoded continuation
    moved onto them. The decoded observation is the tokenizer's reconstruction (tens of mm off, and its
    convolutions read the sampled codes after it), and the trajectory integrates from frame 0, so the
    continuation is joined at the last observed frame (0-based ``observed`` − 1):

    - each wrist is translated by the source's minus the decoded wrist there, for good: the decoded
      trajectory continues from where the hand is, not from where the tokenizer put it;
    - the joints relative to their wrist get the source's minus the decoded pose there, decaying
      linearly to 0 over ``frames`` frames: the first predicted frame starts at the observed pose, and
      the decoded motion's own pose takes over (0: no pull, the pose jumps; −1: over the rest of the clip).
    """
    f = observed
    j = np.array(decoded_RxTx2x21x3, np.float32, copy=True)
    frames = j.shape[1] - f if frames < 0 else frames
    src = np.asarray(source_RxTx2x21x3, np.float32)
    wrist_off = src[:, f - 1, :, :1] - j[:, f - 1, :, :1]  # (R, 2, 1, 3)
    pose_off = (src[:, f - 1] - src[:, f - 1, :, :1]) - (j[:, f - 1] - j[:, f - 1, :, :1])  # (R, 2, 21, 3)
    k = np.arange(1, j.shape[1] - f + 1, dtype=np.float32)  # predicted frame f + k − 1 is k frames after f − 1
    w = np.clip(1.0 - k / (frames + 1), 0.0, 1.0) if frames else np.zeros_like(k)
    j[:, f:] += wrist_off[:, None] + w[None, :, None, None, None] * pose_off[:, None]
    j[:, :f] = src[:, :f]
    return j


def _joined(prompts) -> list[dict]:
    from handx_jax.text.cache import joined_texts

    return joined_texts([{"left": [p.left], "right": [p.right], "interaction": [p.interaction]} for p in prompts])


@dataclass
class ARRun:
    run_dir: Path
    cfg: ARRunConfig
    model: P.PrefixLM
    params: Any
    step: int
    encoder: Any
    tokenizer: Any  # TokenizerRun
    used_ema: bool
    tasks: tuple[str, ...] = TASKS

    def encode(self, prompts) -> tuple[np.ndarray, np.ndarray]:
        """The joined prefix of each prompt, exactly as the joined text cache stores it (same string,
        max_len, zeroed padding and cache-dtype rounding)."""
        texts = _joined(prompts)
        e, h = self.encoder.encode([t["joined"][0] for t in texts], max_len=self.cfg.data.text_max_len)
        m = e.mask_BxL.astype(bool)
        L = int(max(m.sum(1).max(), 1))
        h = (h * m[..., None]).astype(self.cfg.data.cache_dtype).astype(np.float32)
        return h[:, :L], m[:, :L]

    def check_prompts(self, prompts) -> None:
        """Refuse a typed prompt the joined prefix's window would cut (``text.prompts.check_window``): the
        cut drops the prompts after it. ``generate`` itself cuts, as the joined text cache did in training."""
        from handx_jax.text.prompts import check_window

        check_window(self.encoder.tokenizer, prompts, self.cfg.data.text_max_len,
                     joined=lambda p: _joined([p])[0]["joined"][0])

    def generate(self, prompts, opts: GenerateOptions, *, samples: int = 1, task: str = "text2motion", sources=None,
                 keyframes=(30,), fixed_hand: str = "left") -> np.ndarray:
        """G samples per prompt → joints (P, G, 60, 2, 21, 3). Greedy decoding gives G equal samples."""
        if task not in TASKS:
            raise ValueError(f"the ar family does {', '.join(TASKS)}, not {task!r}")
        text, mask = self.encode(prompts)
        n_obs = 0
        observed = np.zeros((len(prompts), 0), np.int32)
        if task == "prediction":
            if sources is None or len(sources) != len(prompts):
                raise ValueError("--task prediction needs one source clip per prompt")
            f = opts.observed_frames  # even and in (0, 60): GenerateOptions checks it
            n_obs = f // 2
            observed = self.tokenizer.encode_clips(np.stack([np.asarray(s)[:f] for s in sources]))
        G = samples
        rows = np.repeat(np.arange(len(prompts)), G)
        rng = jax.random.PRNGKey(opts.seed)
        out = []
        for s in range(0, len(rows), opts.batch_size):
            r = rows[s:s + opts.batch_size]
            pad = opts.batch_size - len(r) if len(rows) > opts.batch_size else 0  # one compiled shape
            rr = np.concatenate([r, np.full(pad, r[-1])])
            toks, lens = AD.decode(self.model, self.params, jnp.asarray(text[rr]), jnp.asarray(mask[rr]),
                                   jnp.asarray(observed[rr][:, :n_obs]), jax.random.fold_in(rng, s), opts.decode,
                                   use_cache=opts.use_cache)
            j = AD.tokens_to_joints(self.tokenizer.model, self.tokenizer.params, np.asarray(toks), np.asarray(lens),
                                    self.tokenizer.norm)
            out.append(j[:len(r)])
        j = np.concatenate(out)
        if task == "prediction":
            src = np.stack([np.asarray(x, np.float32) for x in sources])[rows]
            j = stitch(j, src, opts.observed_frames, opts.stitch_frames)
        return j.reshape(len(prompts), G, *j.shape[1:])

    def generate_long(self, segments, opts, *, samples: int = 1, source=None) -> np.ndarray:
        raise ValueError("the ar family does not do --task long")

    def describe(self, opts: GenerateOptions) -> str:
        d = opts.decode
        how = "greedy" if d.temperature <= 0 else f"T={d.temperature}, top-k {d.top_k}, top-p {d.top_p}"
        how += f", guidance {d.guidance}" if d.guidance != 1 else ""
        return (f"{how} decoding{' with KV cache' if opts.use_cache else ''}, "
                f"{'EMA' if self.used_ema else 'raw'} params at step {self.step}")


def _encoder(encoder, default):
    """A loaded FrozenEncoder as is; a folder (or None: ``default``) loaded."""
    from handx_jax.text.hf import as_encoder

    return as_encoder(default if encoder is None else encoder)


def load(run_dir: str | os.PathLike, *, ema: bool = True, encoder=None, overrides: Sequence[str] = ()) -> ARRun:
    from handx_jax.train import load_params

    run_dir = Path(run_dir)
    doc = run_config(run_dir, FAMILY)
    cfg = generation_config(from_dict(ARRunConfig, doc), overrides)
    enc = _encoder(encoder, cfg.data.encoder)
    want = doc.get("text_cache", {}).get("encoder_fingerprint")
    if want and enc.fingerprint != want:
        raise DataError(f"encoder fingerprint {enc.fingerprint} differs from the one the run was trained with ({want})",
                        path=getattr(enc, "path", None) or encoder or cfg.data.encoder)
    tok = T.load(doc["tokenizer"]["tokenizer_path"])
    if tok.fingerprint != doc["tokenizer"]["tokenizer_fingerprint"]:
        raise DataError("the tokenizer folder changed since this LM was trained (fingerprint "
                        f"{tok.fingerprint}, recorded {doc['tokenizer']['tokenizer_fingerprint']})",
                        path=doc["tokenizer"]["tokenizer_path"])
    params, step = load_params(run_dir, ema=ema)
    return ARRun(run_dir, cfg, P.PrefixLM(cfg.model), params, step, enc, tok, bool(ema and cfg.train.ema_decay > 0))


def init_run(cfg: ARRunConfig, tokenizer_dir, encoder, rng_seed: int = 0) -> ARRun:
    """An UNTRAINED LM (random init) around a trained tokenizer: the baseline a trained LM must beat."""
    tok = T.load(tokenizer_dir)
    enc = _encoder(encoder, encoder)
    m = dataclasses.replace(cfg.model, nb_code=tok.cfg.model.nb_code, text_dim=enc.cfg.d_model)
    cfg = dataclasses.replace(cfg, model=m)
    model, params = P.init_lm(m, jax.random.PRNGKey(rng_seed))
    return ARRun(Path("."), cfg, model, params, 0, enc, tok, False)


# ------------------------------------------------------------------------------------------------
# Command-line hooks of the family interface


def add_train_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", required=True, help="dataset directory (joined text cache + token cache)")
    p.add_argument("--encoder", required=True, help="frozen T5 encoder folder")
    p.add_argument("--tokenizer", required=True, help="tokenizer run folder (`handx train tokenizer`)")


def config_from_args(args: argparse.Namespace) -> ARRunConfig:
    return make_config(args.preset, args.set, data=args.data, encoder=args.encoder, tokenizer=args.tokenizer)


def add_params_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--layers", type=int, help="transformer layers (overrides the preset)")
    p.add_argument("--dim", type=int, help="model width")
    p.add_argument("--heads", type=int, help="attention heads")
    p.add_argument("--codebook", type=int, default=4096, help="NOMINAL codebook size; the real one sets the vocabulary")
    p.add_argument("--text-dim", type=int, default=768, help="text feature width (768 for T5-base)")
    p.add_argument("--text-len", type=int, default=96, help="joined-prefix tokens for the FLOPs count")
    p.add_argument("--encoder", help="encoder folder for text_flops_per_sample (default: T5-base)")


def params_from_args(args: argparse.Namespace) -> tuple[str, dict]:
    from handx_jax.models.fsq import real_codebook_size

    nb = real_codebook_size(args.codebook)
    sizes = [f"model.{k}={v}" for k, v in (("layers", args.layers), ("dim", args.dim), ("heads", args.heads),
                                          ("text_dim", args.text_dim), ("nb_code", nb)) if v is not None]
    cfg = make_config(args.preset, [*sizes, *args.set])
    enc_cfg = None
    if args.encoder:
        from handx_jax.text.hf import load_hf_t5_encoder

        enc_cfg = load_hf_t5_encoder(args.encoder).cfg
    m = cfg.model
    label = (f"ar {cfg.preset}: L{m.layers} d{m.dim} H{m.heads} SwiGLU {m.hidden}, codebook {args.codebook} "
             f"({nb} codes), text {m.text_dim}-d, {args.text_len} prefix tokens")
    return label, numbers(cfg, text_len=args.text_len, encoder_cfg=enc_cfg)


def add_generate_args(p) -> None:
    p.add_argument("--temperature", type=float, help="sampling temperature >= 0 (default: the run's, 0 = greedy)")
    p.add_argument("--top-k", type=int, help="keep the k most likely tokens, k >= 0 (0 = off)")
    p.add_argument("--top-p", type=float, help="nucleus mass in (0, 1] (1 = off)")
    p.add_argument("--guidance", type=float,
                   help="classifier-free guidance scale s >= 0 on the logits (1 = off; for runs trained with data.text_drop)")
    p.add_argument("--observed-frames", type=int, default=20,
                   help="--task prediction: observed frames, even and in (0, 60) (default 20)")
    p.add_argument("--stitch-frames", type=int, default=GenerateOptions.stitch_frames,
                   help="--task prediction: frames over which the continuation's hand pose is pulled from the "
                        "observed last frame's to its own (default -1: the rest of the clip; 0 = none)")
    p.add_argument("--no-kv-cache", action="store_true", help="recompute the whole sequence every step")


def load_for_generate(args: argparse.Namespace, *, ema: bool, encoder, seed: int, batch_size: int):
    from handx_jax.text.prompts import typed_prompts

    pick = lambda v, d: d if v is None else v  # noqa: E731
    d = AD.DecodeOptions()
    # The flags' range checks (DecodeOptions, GenerateOptions) before the run is read.
    GenerateOptions(AD.DecodeOptions(pick(args.temperature, d.temperature), pick(args.top_k, d.top_k),
                                     pick(args.top_p, d.top_p), pick(args.guidance, d.guidance)),
                    observed_frames=args.observed_frames, stitch_frames=args.stitch_frames)
    run = load(args.run, ema=ema, encoder=encoder, overrides=args.set)
    run.check_prompts(typed_prompts(args))
    s = run.cfg.sample
    dec = AD.DecodeOptions(temperature=pick(args.temperature, s.temperature), top_k=pick(args.top_k, s.top_k),
                           top_p=pick(args.top_p, s.top_p), guidance=pick(args.guidance, s.guidance))
    return run, GenerateOptions(decode=dec, seed=seed, batch_size=batch_size, observed_frames=args.observed_frames,
                                use_cache=not args.no_kv_cache, stitch_frames=args.stitch_frames)
