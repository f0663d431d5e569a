"""The FSQ motion-tokenizer family (paper §5.2; reference §4.1–4.4): training, loading, the token cache.

    handx train tokenizer --data DIR --preset paper --set model.codebook=4096 --out TOK
    handx data tokens --tokenizer TOK --data DIR       # DIR/token_cache/<fingerprint>/codes.npy

Training items are 48-frame windows of the train split's clips at every start 0..12 (13 per clip,
§4.3), in the normalised 288-d AR representation (§2.4, the dataset's ``ar`` stats). The loss is the
§4.3 sum (``models.fsq.tokenizer_loss``). Every ``train.eval_every`` steps and at the end the hook
logs, on up to ``data.eval_clips`` full clips of the val split: MPJPE in mm (per hand, relative to
its wrist, de-normalised), codebook usage and perplexity.

A trained tokenizer is one per (dataset, codebook): ``handx data tokens`` encodes every clip once
(30 codes each) into a token cache that every LM size trains from. The cache's fingerprint hashes
the dataset and the tokenizer's parameters, so an LM run can name exactly the tokenizer it used.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.config import ConfigError, apply_overrides, from_dict, get_preset, to_dict
from handx_jax.families import entry, run_config
from handx_jax.infra.errors import DataError
from handx_jax.models import fsq as Q
from handx_jax.optim import OptimConfig
from handx_jax.train import TrainConfig

FAMILY = "tokenizer"
NORM = entry(FAMILY).norm_preset().name  # the stats.npz prefix its registry entry declares
NORM_FILE = "norm_stats.npz"
WINDOW_STARTS = 13  # 60-frame clips, 48-frame windows at starts 0..12 (§4.3)
TOKEN_CACHE_DIRNAME = "token_cache"
TOKEN_FORMAT, TOKEN_FORMAT_VERSION = "handx-jax-token-cache", 1
PRESETS = Q.PRESETS


@dataclass(frozen=True)
class DataConfig:
    path: str = ""  # dataset directory
    fraction: float = 1.0  # nested train subset
    window: int = 48  # training window in frames (§4.3)
    eval_clips: int = 512  # val clips for the MPJPE / usage hook


# Reference §4.3: batch 512, AdamW(2e-4, (0.9, 0.99), wd 0), 8000 warm-up steps, no clipping. The
# reference's ×0.1 steps at 50% and 75% of 600k iterations are not reproduced (the shared loop has
# constant and cosine schedules); cosine to 0 is the default here.
REFERENCE_TRAIN = TrainConfig(steps=600000, batch_size=512, log_every=100, ckpt_every=5000, eval_every=8000,
                              optim=OptimConfig(lr=2e-4, b1=0.9, b2=0.99, weight_decay=0.0, warmup_steps=8000,
                                                schedule="cosine", grad_clip=0.0))
# The CPU presets' recipe: a run of minutes on 2 cores (``small`` on the 1,200-clip standard prefix:
# 0.33–0.42 CPU-s per step, ~18 CPU-minutes for the 3,000 steps, val MPJPE 21.8 mm = 0.32× the mean
# pose; docs/results/ar_tokenizer/). The reference's 600k × 512 windows are
# out of reach there, so fewer, smaller batches at a 10× higher peak (stable at 2e-3 for these widths
# with the ``latent`` bound of models.fsq), a short warm-up and cosine to 0 at the end of the run.
CPU_TRAIN = TrainConfig(steps=3000, batch_size=64, log_every=100, ckpt_every=1000, eval_every=500,
                        optim=OptimConfig(lr=2e-3, b1=0.9, b2=0.99, weight_decay=0.0, warmup_steps=100,
                                          schedule="cosine", grad_clip=1.0))
# ``small`` warms up over 500 steps, not 100. At 100, on corpus v5's 4,000-clip prefix with seed 42, every channel
# of the decoder's last ReLU (conv_mid) was negative on every frame by step 25, as lr reached 2e-3: the
# decoder put out its bias, the mean pose, and stayed there (val MPJPE 58.3 mm against the mean pose's 60.9 mm
# for all 3,000 steps, grad norm 0.2-0.4 against 3-8 for a live run; docs/results/validity/v8-tokenizer/). The
# early gradients are large (norm 34 at step 5), and Adam moves every kernel weight by ~lr whatever their size,
# so 384 non-negative inputs per channel shift its pre-activation by up to ~0.8 per step. With 500 steps the
# same seed and data train (35.7 mm at step 500, at the peak lr). ``tiny`` keeps 100 (its tests' short runs).
SMALL_TRAIN = dataclasses.replace(CPU_TRAIN, optim=dataclasses.replace(CPU_TRAIN.optim, warmup_steps=500))
TRAIN_PRESETS = {"tiny": CPU_TRAIN, "small": SMALL_TRAIN, "paper": REFERENCE_TRAIN}
# A tokenizer whose validation error stays this close to the mean pose's after COLLAPSE_AFTER steps reconstructs
# nothing (a dead decoder, above): said on stderr at each evaluation rather than found by a downstream study.
COLLAPSE_RATIO, COLLAPSE_AFTER = 0.9, 500
LOSSES = tuple(Q.LOSS_PRESETS)


@dataclass(frozen=True)
class TokenizerRunConfig:
    preset: str = "tiny"
    model: Q.FSQConfig = PRESETS["tiny"]
    train: TrainConfig = CPU_TRAIN  # the preset's recipe (TRAIN_PRESETS)
    data: DataConfig = field(default_factory=DataConfig)
    # Loss weights (models.fsq.LOSS_PRESETS): "hands" (default) adds terms on the joints the reconstructed
    # wrist rotation and root trajectory place; "reference" is §4.3's weights as published.
    loss: str = "hands"

    def validate(self) -> None:
        m = self.model
        if self.loss not in Q.LOSS_PRESETS:
            raise ConfigError(f"loss must be one of {LOSSES}, got {self.loss!r}")
        if m.codebook not in Q.LEVELS:
            raise ConfigError(f"model.codebook {m.codebook} has no FSQ levels; choose from {sorted(Q.LEVELS)}")
        if m.quantizer not in Q.QUANTIZERS:
            raise ConfigError(f"model.quantizer must be one of {Q.QUANTIZERS}, got {m.quantizer!r}")
        if self.data.window % (2 ** m.down_t) or not 0 < self.data.window <= 60:
            raise ConfigError(f"data.window {self.data.window} must be in (0, 60] and divisible by {2 ** m.down_t}")
        if not 0 < self.data.fraction <= 1:
            raise ConfigError(f"data.fraction must be in (0, 1], got {self.data.fraction}")


Config = TokenizerRunConfig


def make_config(preset: str = "tiny", overrides: Sequence[str] = (), *, data: str = "") -> TokenizerRunConfig:
    cfg = TokenizerRunConfig(preset=preset, model=get_preset(PRESETS, preset, "tokenizer preset"),
                             train=TRAIN_PRESETS[preset],
                             data=DataConfig(path=str(Path(data).absolute()) if data else ""))
    return apply_overrides(cfg, overrides)


def numbers(cfg: TokenizerRunConfig, **_) -> dict:
    """Parameters and analytic forward FLOPs per training window (no text encoder)."""
    n = Q.param_count(cfg.model)
    return {"params": n, "params_non_embedding": n, "flops_per_sample": Q.forward_flops(cfg.model, cfg.data.window),
            "text_flops_per_sample": 0}


# ------------------------------------------------------------------------------------------------
# Data


# Train splits whose normalised features take at most this many bytes are featurised once, up front
# (1,085 clips of the 1,200-clip prefix: 75 MB); larger ones per batch. Per batch, ``to_ar`` of 64 clips
# costs ~80 ms of CPU, as much as a tiny tokenizer's whole training step on 2 cores.
PRECOMPUTE_BYTES = 256 << 20


@dataclass
class TrainData:
    motion: Any  # (N, 60, 2, 21, 3) memory map
    clips: np.ndarray  # train clip indices
    window: int
    norm: Any  # NormStats (NORM)
    features: np.ndarray | None = None  # (len(clips), 60, 288) normalised float32, when precomputed

    def __post_init__(self):
        if self.features is None and len(self.clips) * 60 * 288 * 4 <= PRECOMPUTE_BYTES:
            order = np.sort(self.clips)
            f = np.concatenate([self._features(order[s:s + 256]) for s in range(0, len(order), 256)])
            self.features = f[np.searchsorted(order, self.clips)]

    @property
    def num_items(self) -> int:
        return len(self.clips) * WINDOW_STARTS

    def _features(self, sorted_clips: np.ndarray) -> np.ndarray:
        """Normalised AR features of whole clips (the velocities at a window's last frame are real, not 0)."""
        from handx_jax import representation as rep

        return self.norm.normalize(rep.to_ar(np.asarray(self.motion[sorted_clips], np.float64))).astype(np.float32)

    def batch(self, idx: np.ndarray) -> dict:
        """Windows of the normalised AR features, computed on the whole clip and then cut."""
        ci, start = np.asarray(idx) // WINDOW_STARTS, np.asarray(idx) % WINDOW_STARTS
        if self.features is not None:
            f = self.features[ci]
        else:
            f = self._features(np.sort(self.clips[ci]))
            f = f[np.argsort(np.argsort(self.clips[ci], kind="stable"), kind="stable")]
        take = start[:, None] + np.arange(self.window)[None]
        return {"x": np.take_along_axis(f, take[..., None], axis=1)}


def _ar_norm(ds):
    from handx_jax import representation as rep

    try:
        return rep.NormStats.from_npz_dict(ds.stats, NORM, path=ds.root / "stats.npz")
    except KeyError as e:
        raise DataError(f"stats.npz has no AR statistics ({e}); rebuild the dataset", path=ds.root) from None


def _norm_arrays(norm):
    return jnp.asarray(norm.mean), jnp.asarray(norm.std + np.float32(norm.eps))


# ------------------------------------------------------------------------------------------------
# Training


def make_loss(model: Q.FSQTokenizer, norm, weights: str = "hands"):
    mean, scale = _norm_arrays(norm)

    def loss(params, batch, rng, train: bool):
        x = batch["x"]
        xhat, _, y = model.apply(params, x, method=model.reconstruct)
        return Q.tokenizer_loss(xhat.astype(jnp.float32), x, mean, scale, weights, latent=y)

    return loss


# Keys of the hook's row: models.fsq.reconstruction_errors' names → metrics.jsonl names.
EVAL_KEYS = {"mpjpe": "eval/mpjpe_mm", "fingers": "eval/fingers_mm", "wrist_orient": "eval/wrist_orient_mm",
             "root": "eval/root_mm", "global": "eval/global_mpjpe_mm"}


def make_evaluate(model: Q.FSQTokenizer, cfg: Q.FSQConfig, x_val_n, norm):
    """Validation hook on full clips (§4.3), every ``eval_every`` steps: MPJPE in mm in each hand's wrist
    frame with the orientation applied (the reference's number), its split into fingers / wrist orientation
    / root trajectory (``models.fsq.reconstruction_errors``), the global MPJPE with the root trajectory
    integrated, the mean pose's MPJPE on the same clips (``mean_pose_*``; the normalised zero frame, a
    constant, the floor any reconstruction must beat) and their ratio, codebook usage and perplexity."""
    mean, scale = _norm_arrays(norm)
    B = 64

    @jax.jit
    def one(params, x):
        xhat, digits = model.apply(params, x)
        return Q.reconstruction_errors(xhat * scale + mean, x * scale + mean), Q.digits_to_index(digits, cfg.levels)

    @jax.jit
    def mean_pose(x):
        gt = x * scale + mean
        return Q.reconstruction_errors(jnp.broadcast_to(mean, gt.shape), gt)

    def batches():
        for s in range(0, len(x_val_n), B):
            yield jnp.asarray(x_val_n[s:s + B])

    base = [mean_pose(x) for x in batches()]
    baseline = {k: float(np.concatenate([np.asarray(b[k]) for b in base]).mean()) for k in ("mpjpe", "global")}

    def evaluate(params, ema, step):
        errs, codes = [], []
        for x in batches():
            e, c = one(params, x)
            errs.append(jax.device_get(e))
            codes.append(np.asarray(c))
        st = Q.codebook_stats(np.concatenate(codes), cfg.nb_code)
        row = {EVAL_KEYS[k]: float(np.concatenate([e[k] for e in errs]).mean()) for k in EVAL_KEYS}
        warning = collapse_warning(row["eval/mpjpe_mm"], baseline["mpjpe"], step)
        if warning:
            print(warning, file=sys.stderr, flush=True)
        return {**row, "eval/mean_pose_mpjpe_mm": baseline["mpjpe"], "eval/mean_pose_global_mm": baseline["global"],
                "eval/mpjpe_vs_mean_pose": row["eval/mpjpe_mm"] / baseline["mpjpe"],
                "eval/usage": st["usage"], "eval/perplexity": st["perplexity"], "eval/codes_used": st["codes_used"]}

    return evaluate


def collapse_warning(mpjpe_mm: float, mean_pose_mm: float, step: int) -> str | None:
    """The line a collapsed tokenizer's evaluation prints (``COLLAPSE_RATIO``), or None."""
    if step < COLLAPSE_AFTER or mpjpe_mm < COLLAPSE_RATIO * mean_pose_mm:
        return None
    return (f"warning: tokenizer at step {step} reconstructs no better than the mean pose (val MPJPE {mpjpe_mm:.1f} mm, "
            f"the mean pose {mean_pose_mm:.1f} mm): its decoder has likely collapsed; retrain with a longer "
            f"train.optim.warmup_steps or a lower train.optim.lr")


RESUME_KEYS = ("model", "data", "train", "loss")


def run_record(cfg: TokenizerRunConfig, ds) -> dict:
    return {"family": FAMILY, "preset": cfg.preset, "model": to_dict(cfg.model), "data": to_dict(cfg.data),
            "loss": cfg.loss,
            "data_fraction": cfg.data.fraction, "dataset_fingerprint": ds.fingerprint,
            "codebook": cfg.model.codebook, "nb_code": cfg.model.nb_code, "levels": list(cfg.model.levels),
            **numbers(cfg)}


def train(run_dir: str | os.PathLike, cfg: TokenizerRunConfig, *, stop_at: int | None = None, on_log=None,
          encoder=None) -> dict:
    """Train (or resume) a tokenizer in ``run_dir`` (``encoder`` is unused: no text)."""
    from handx_jax import representation as rep
    from handx_jax import train as loop
    from handx_jax.dataset.format import Dataset

    cfg.validate()
    if not cfg.data.path:
        raise ConfigError("data.path is empty: give --data DIR")
    run_dir = Path(run_dir)
    ds = Dataset.open(cfg.data.path)
    clips = np.asarray(ds.split("train", cfg.data.fraction))
    if not len(clips):
        raise DataError("the train split is empty", path=cfg.data.path)
    norm = _ar_norm(ds)
    val = np.asarray(ds.split("val"))
    val = val if len(val) else np.asarray(ds.split("test"))
    val = val[: cfg.data.eval_clips]
    x_val = norm.normalize(rep.to_ar(np.asarray(ds.motion[val], np.float64))).astype(np.float32) if len(val) else None
    record = run_record(cfg, ds)
    loop.check_resume(run_dir, {**record, "train": to_dict(cfg.train)}, RESUME_KEYS)
    run_dir.mkdir(parents=True, exist_ok=True)
    if jax.process_index() == 0:
        np.savez(run_dir / NORM_FILE, **norm.to_npz_dict(NORM))
    model = Q.FSQTokenizer(cfg.model)
    data = TrainData(ds.motion, clips, cfg.data.window, norm)
    return loop.train(run_dir, loop.TrainSpec(
        init=lambda rng: Q.init_tokenizer(cfg.model, rng, cfg.data.window)[1], loss=make_loss(model, norm, cfg.loss),
        cfg=cfg.train, config=record, get_batch=data.batch, num_examples=data.num_items,
        evaluate=None if x_val is None else make_evaluate(model, cfg.model, x_val, norm),
        flops_per_sample=record["flops_per_sample"], resume_keys=RESUME_KEYS), stop_at=stop_at, on_log=on_log)


# ------------------------------------------------------------------------------------------------
# Loading, encoding, decoding


@dataclass
class TokenizerRun:
    run_dir: Path
    cfg: TokenizerRunConfig
    model: Q.FSQTokenizer
    params: Any
    step: int
    norm: Any  # NormStats (NORM)
    record: dict

    tasks: tuple[str, ...] = ()  # a tokenizer does not generate from text

    @property
    def fingerprint(self) -> str:
        """Hash of the tokenizer's configuration and parameter bytes."""
        h = hashlib.sha256(json.dumps({k: self.record[k] for k in ("model", "codebook", "nb_code")},
                                      sort_keys=True).encode())
        for leaf in jax.tree_util.tree_leaves(self.params):
            h.update(np.ascontiguousarray(np.asarray(leaf, np.float32)).tobytes())
        return h.hexdigest()[:16]

    def encode_clips(self, joints_NxTx2x21x3, batch_size: int = 256) -> np.ndarray:
        """Joints → codes (N, T/2) int32 (normalised AR features, §4.4)."""
        from handx_jax import representation as rep

        enc = jax.jit(lambda p, x: self.model.apply(p, x, method=self.model.encode))
        out = []
        for s in range(0, len(joints_NxTx2x21x3), batch_size):
            x = self.norm.normalize(rep.to_ar(np.asarray(joints_NxTx2x21x3[s:s + batch_size], np.float64)))
            out.append(np.asarray(enc(self.params, jnp.asarray(x, jnp.float32))))
        return np.concatenate(out).astype(np.int32)

    def generate(self, *a, **kw):
        raise ValueError("a tokenizer run does not generate from text; train an `ar` run on its token cache")

    def generate_long(self, *a, **kw):
        raise ValueError("a tokenizer run does not generate from text")

    def describe(self, opts) -> str:
        return f"FSQ tokenizer ({self.cfg.model.codebook}/{self.cfg.model.nb_code} codes) at step {self.step}"


def load(run_dir: str | os.PathLike, *, ema: bool = True, encoder=None, overrides: Sequence[str] = ()) -> TokenizerRun:
    from handx_jax import representation as rep
    from handx_jax.train import load_params

    run_dir = Path(run_dir)
    doc = run_config(run_dir, FAMILY)
    cfg = from_dict(TokenizerRunConfig, doc)
    params, step = load_params(run_dir, ema=ema)
    norm = rep.NormStats.read(run_dir / NORM_FILE, NORM)
    return TokenizerRun(run_dir, cfg, Q.FSQTokenizer(cfg.model), params, step, norm, doc)


def token_cache_fingerprint(dataset_fp: str, tokenizer_fp: str) -> str:
    doc = {"format": TOKEN_FORMAT, "version": TOKEN_FORMAT_VERSION, "dataset": dataset_fp, "tokenizer": tokenizer_fp}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def tokenize(tokenizer_dir: str | os.PathLike, data_dir: str | os.PathLike, *, overwrite: bool = False,
             log=print) -> Path:
    """Encode every clip of the dataset (all splits) into ``DATA/token_cache/<fp>/`` (atomic):
    ``codes.npy`` (N, 30) int32 in dataset clip order and ``meta.json`` (provenance: the tokenizer
    folder, its fingerprint, step, nominal and real codebook size, levels, quantizer; the dataset)."""
    from handx_jax.dataset.format import Dataset
    from handx_jax.infra.atomic import atomic_dir, atomic_write_json

    tok = load(tokenizer_dir)
    ds = Dataset.open(data_dir)
    if tok.record.get("dataset_fingerprint") not in (None, ds.fingerprint):
        log(f"note: tokenizer {tokenizer_dir} was trained on dataset {tok.record['dataset_fingerprint']}, "
            f"encoding dataset {ds.fingerprint}")
    tfp = tok.fingerprint
    fp = token_cache_fingerprint(ds.fingerprint, tfp)
    out = Path(data_dir) / TOKEN_CACHE_DIRNAME / fp
    if out.exists() and not overwrite:
        log(f"token cache {out} is up to date")
        return out
    codes = tok.encode_clips(ds.motion)
    counts = np.bincount(codes.reshape(-1), minlength=tok.cfg.model.nb_code)
    with atomic_dir(out, overwrite=overwrite) as tmp:
        np.save(tmp / "codes.npy", codes)
        atomic_write_json(tmp / "meta.json", {
            "format": TOKEN_FORMAT, "format_version": TOKEN_FORMAT_VERSION, "fingerprint": fp,
            "dataset_fingerprint": ds.fingerprint, "tokenizer_fingerprint": tfp,
            "tokenizer_path": str(Path(tokenizer_dir).absolute()), "tokenizer_step": tok.step,
            "codebook": tok.cfg.model.codebook, "nb_code": tok.cfg.model.nb_code, "levels": list(tok.cfg.model.levels),
            "quantizer": tok.cfg.model.quantizer, "num_clips": int(codes.shape[0]), "tokens_per_clip": int(codes.shape[1]),
            "codes_used": int((counts > 0).sum())})
    log(f"token cache {out}: {codes.shape[0]} clips × {codes.shape[1]} codes, "
        f"{int((counts > 0).sum())}/{tok.cfg.model.nb_code} codes used")
    return out


@dataclass
class TokenCache:
    root: Path
    meta: dict
    codes: np.ndarray  # (N, 30) int32

    @classmethod
    def open(cls, root: str | os.PathLike, *, dataset_fingerprint: str | None = None) -> "TokenCache":
        from handx_jax.infra.readers import read_format_meta

        root = Path(root)
        meta = read_format_meta(root / "meta.json", TOKEN_FORMAT, TOKEN_FORMAT_VERSION,
                                missing="not a token cache (missing meta.json); build one with `handx data tokens`",
                                upgrade="; rebuild it with `handx data tokens`")
        if dataset_fingerprint is not None and meta["dataset_fingerprint"] != dataset_fingerprint:
            raise DataError(f"token cache built for dataset {meta['dataset_fingerprint']}, not {dataset_fingerprint}; "
                            "run `handx data tokens` on this dataset", path=root)
        return cls(root, meta, read_codes(root / "codes.npy", meta))


def read_codes(path: Path, meta: dict) -> np.ndarray:
    """The cache's codes, checked before any training reads them: readable (a truncated file names
    itself), of the shape meta.json gives, integers, and inside the tokenizer's codebook [0, nb_code).
    A code outside it is a token the LM has no row for: training went on to a NaN loss at step 5 and
    left a run folder behind (issue 31)."""
    from handx_jax.infra.readers import read_npy

    try:
        codes = read_npy(path, missing="missing codes.npy; rebuild the cache with `handx data tokens`")
    except DataError as e:
        if "missing codes.npy" in str(e):
            raise
        raise DataError(f"{e}; rebuild it with `handx data tokens`") from None
    if codes.shape != (meta["num_clips"], meta["tokens_per_clip"]):
        raise DataError(f"codes shape {codes.shape} does not match meta.json's ({meta['num_clips']}, "
                        f"{meta['tokens_per_clip']}); rebuild it with `handx data tokens`", path=path)
    if codes.dtype.kind not in "iu":
        raise DataError(f"codes must be integers, got dtype {codes.dtype}; rebuild it with `handx data tokens`",
                        path=path)
    nb = int(meta["nb_code"])
    bad = (codes < 0) | (codes >= nb)
    if bad.any():
        row, col = (int(v) for v in np.argwhere(bad)[0])
        raise DataError(f"{int(bad.sum())} codes outside the codebook [0, {nb}) of tokenizer "
                        f"{meta.get('tokenizer_fingerprint', '?')}, the first {int(codes[row, col])} at clip {row}, "
                        f"token {col}; rebuild it with `handx data tokens`", path=path)
    return codes


def open_token_cache(data_dir: str | os.PathLike, tokenizer_dir: str | os.PathLike) -> TokenCache:
    """The cache of this dataset + tokenizer, verified; a clear error naming the command if absent."""
    from handx_jax.dataset.format import Dataset

    ds = Dataset.open(data_dir)
    fp = token_cache_fingerprint(ds.fingerprint, load(tokenizer_dir).fingerprint)
    root = Path(data_dir) / TOKEN_CACHE_DIRNAME / fp
    if not root.exists():
        raise DataError(f"no token cache for this dataset + tokenizer; run `handx data tokens --tokenizer "
                        f"{tokenizer_dir} --data {data_dir}`", path=root.parent)
    return TokenCache.open(root, dataset_fingerprint=ds.fingerprint)


# ------------------------------------------------------------------------------------------------
# Command-line hooks of the family interface


def add_train_args(p: argparse.ArgumentParser) -> None:
    # The codebook size (model.codebook, nominal: 512 by default; models.fsq.LEVELS lists the sizes) and the quantiser
    # (model.quantizer: paper = round(σ(y)(L−1)), fsq = the reference code's tanh form) are config keys
    # like any other: --set model.codebook=4096, one channel for the command line and the sweeps.
    p.add_argument("--data", required=True, help="dataset directory")


def config_from_args(args: argparse.Namespace) -> TokenizerRunConfig:
    return make_config(args.preset, args.set, data=args.data)


def add_params_args(p: argparse.ArgumentParser) -> None:
    pass  # the codebook size is --set model.codebook=N, as for training


def params_from_args(args: argparse.Namespace) -> tuple[str, dict]:
    cfg = make_config(args.preset, args.set)
    m = cfg.model
    return f"tokenizer {cfg.preset}: width {m.width}, levels {m.levels} ({m.nb_code} codes)", numbers(cfg)


def add_generate_args(p) -> None:
    pass


def load_for_generate(args: argparse.Namespace, *, ema: bool, encoder, seed: int, batch_size: int):
    return load(args.run, ema=ema), None
