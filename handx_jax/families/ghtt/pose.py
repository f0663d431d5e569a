"""G-HTT's pose block P (§3.1), trained first (§3.3): a shared step of every G-HTT run, as the FSQ
tokenizer is of the AR LM (``Family.needs``).

    handx train ghtt-pose --data DIR --preset tiny --out POSE
    handx train ghtt --data DIR --encoder ENC --ghtt-pose POSE --out RUN

Training items are (clip, start) pairs of the train split: two consecutive spans of t = 15 frames from
any start. E^P reads the first span (augmented, App. B.3), D^P predicts the second from m ~ N(μ^P, Σ^P);
the loss is Eq. 1 (L1 over both spans' frames, normalised units, summed over the 153 values, mean over
frames) + Eq. 2 (L1 of the predicted span's accumulated palm poses, 6D rotation + translation in cm) +
λ3 KL. The frame statistics are the train clips' (``ghtt_norm.npz`` in the run folder).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.config import ConfigError, apply_overrides, from_dict, get_preset, to_dict
from handx_jax.families import run_config
from handx_jax.families.ghtt import common as C
from handx_jax.models import ghtt as G
from handx_jax.models import ghtt_motion as HM
from handx_jax.optim import OptimConfig
from handx_jax.train import TrainConfig

FAMILY = "ghtt-pose"
PRESETS = G.PRESETS


@dataclass(frozen=True)
class DataConfig:
    path: str = ""
    fraction: float = 1.0


@dataclass(frozen=True)
class LossConfig:
    """§3.3's weights: λ1 = λ2 = 1, λ3 = 1e-5."""

    comp: float = 1.0
    trj: float = 1.0
    kl: float = 1e-5


# §3.3: AdamW, lr 1e-4, weight decay 0.01, batch 256, 80 epochs. The CPU sizes take a short recipe at a
# higher rate (minutes on 2 cores); the paper preset keeps the paper's.
PAPER_TRAIN = TrainConfig(steps=80 * 3600 * 31 // 256, batch_size=256, log_every=100, ckpt_every=5000,
                          optim=OptimConfig(lr=1e-4, b1=0.9, b2=0.999, weight_decay=0.01, warmup_steps=1000))
CPU_TRAIN = dataclasses.replace(PAPER_TRAIN, steps=1000, batch_size=64, log_every=50, ckpt_every=1000,
                                optim=dataclasses.replace(PAPER_TRAIN.optim, lr=1e-3, warmup_steps=50))
TRAIN_PRESETS = {name: (PAPER_TRAIN if name == "paper" else CPU_TRAIN) for name in PRESETS}


@dataclass(frozen=True)
class PoseRunConfig:
    preset: str = "tiny"
    model: G.GHTTConfig = PRESETS["tiny"]
    train: TrainConfig = CPU_TRAIN
    data: DataConfig = field(default_factory=DataConfig)
    aug: C.AugConfig = C.AugConfig()
    loss: LossConfig = LossConfig()

    def validate(self) -> None:
        for name, b in (("pose", self.model.pose), ("action", self.model.action)):
            if b.dim % b.heads or b.dim % 4:
                raise ConfigError(f"model.{name}.dim {b.dim} must be a multiple of 4 and of model.{name}.heads {b.heads}")
        if not 0 < self.data.fraction <= 1:
            raise ConfigError(f"data.fraction must be in (0, 1], got {self.data.fraction}")
        if not 1 < self.model.span <= 30:
            raise ConfigError(f"model.span must be in [2, 30] (two spans fit a 60-frame clip), got {self.model.span}")


Config = PoseRunConfig


def make_config(preset: str = "tiny", overrides: Sequence[str] = (), *, data: str = "") -> PoseRunConfig:
    cfg = PoseRunConfig(preset=preset, model=get_preset(PRESETS, preset, "G-HTT preset"), train=TRAIN_PRESETS[preset],
                        data=DataConfig(path=str(Path(data).absolute()) if data else ""))
    return apply_overrides(cfg, overrides)


def numbers(cfg: PoseRunConfig, **kw) -> dict:
    n, f = G.param_counts(cfg.model), G.forward_flops(cfg.model)
    emb = 2 * cfg.model.pose.dim
    return {"params": n["params_pose"], "params_non_embedding": n["params_pose"] - emb,
            "flops_per_sample": f["pose"] * 2 // (60 // cfg.model.span),  # one training item: two spans
            "text_flops_per_sample": 0}


# ------------------------------------------------------------------------------------------------
# Loss


def make_loss(cfg: PoseRunConfig, norm: C.Norm):
    t, mean, std = cfg.model.span, jnp.asarray(norm.mean), jnp.asarray(norm.std)
    lam = cfg.loss

    def loss(params, batch, rng, train: bool):
        H = batch["H"]  # (B, 2t, 153) raw
        k_aug, k_m = jax.random.split(rng)
        x = C.augment(k_aug, H[:, :t], cfg.aug) if train else H[:, :t]
        mu, logvar, refined = G.pose_encode(params, cfg.model, (x - mean) / std)
        m = G.reparameterize(k_m, mu, logvar) if train else mu
        pred = G.pose_decode(params, cfg.model, m)
        out = jnp.concatenate([refined, pred], 1)
        comp = jnp.mean(jnp.sum(jnp.abs(out - (H - mean) / std), -1))  # Eq. 1
        B = H.shape[0]
        v_hat = (pred * std + mean)[..., HM.V_SLICE].reshape(B, t, 2, HM.RIGID)
        v_gt = H[:, t:, HM.V_SLICE].reshape(B, t, 2, HM.RIGID)
        cm = jnp.asarray([1.0] * 6 + [100.0] * 3)  # translations in cm
        trj = jnp.mean(jnp.sum(jnp.abs(HM.trajectory(v_hat) - HM.trajectory(v_gt)) * cm, (-1, -2)))  # Eq. 2
        kl = jnp.mean(G.kl_normal(mu, logvar))
        total = lam.comp * comp + lam.trj * trj + lam.kl * kl
        return total, {"comp": comp, "trj": trj, "kl": kl}

    return loss


# ------------------------------------------------------------------------------------------------
# Joint errors of P on whole clips (its evaluation hook, and the fitting test)


@functools.partial(jax.jit, static_argnames=("cfg",))
def _span_joints(params, cfg: G.GHTTConfig, mean, std, x_NxTx2x21x3):
    """E^P's refined first span and D^P's predicted next one (m = μ^P) as joints, placed from the GT palm frames
    before each span: one program (op by op, a tiny P's evaluation compiled ~100 one-op programs)."""
    t = cfg.span
    H, (R, o), scale = jax.vmap(HM.to_frames)(x_NxTx2x21x3)
    mu, _, refined = G.pose_encode(params, cfg, (H[:, :t] - mean) / std)
    pred = G.pose_decode(params, cfg, mu)
    out = jnp.concatenate([refined, pred], 1) * std + mean

    def place(Hs, R, o, s):
        rec = HM.from_frames(Hs[:t], R[0], o[0], s)
        nxt = HM.from_frames(Hs[t:], R[t - 1], o[t - 1], s, first_is_anchor=False)
        return jnp.concatenate([rec, nxt])

    return jax.vmap(place)(out, R, o, scale)


def span_errors_mm(params, cfg: G.GHTTConfig, norm: C.Norm, joints_NxFx2x21x3) -> dict:
    """For each clip's first two spans: the joints of E^P's refined span and of D^P's predicted next span
    (m = μ^P, deterministic), placed from the GT palm frames before each span, against GT; MPJPE-RA (each
    hand relative to its wrist) in mm, beside the train-independent reference of the clip's mean pose."""
    t = cfg.span
    x = np.asarray(joints_NxFx2x21x3, np.float32)[:, :2 * t]
    got = np.asarray(_span_joints(params, cfg, jnp.asarray(norm.mean), jnp.asarray(norm.std), jnp.asarray(x)))
    ra = lambda a: a - a[..., :1, :]  # noqa: E731
    err = 1000 * np.linalg.norm(ra(got) - ra(x), axis=-1).mean((0, 2, 3))  # per frame
    mean_pose = ra(x).mean((0, 1), keepdims=True)
    base = 1000 * np.linalg.norm(mean_pose - ra(x), axis=-1).mean()
    return {"recon_mm": float(err[:t].mean()), "pred_mm": float(err[t:].mean()), "mean_pose_mm": float(base)}


# ------------------------------------------------------------------------------------------------
# Training


def train(run_dir: str | os.PathLike, cfg: PoseRunConfig, *, stop_at=None, on_log=None, encoder=None) -> dict:
    from handx_jax import train as loop
    from handx_jax.dataset.format import Dataset
    from handx_jax.infra.errors import DataError

    cfg.validate()
    if not cfg.data.path:
        raise ConfigError("data.path is empty: give --data")
    ds = Dataset.open(cfg.data.path)
    clips = np.asarray(ds.split("train", cfg.data.fraction))
    if not len(clips):
        raise DataError("the train split is empty", path=cfg.data.path)
    H = C.clip_frames(ds.motion[clips])
    norm = C.fit_norm(H)
    run_dir = Path(run_dir)
    t = cfg.model.span
    starts = H.shape[1] - 2 * t + 1
    record = {"family": FAMILY, "preset": cfg.preset, "model": to_dict(cfg.model), "data": to_dict(cfg.data),
              "aug": to_dict(cfg.aug), "loss": to_dict(cfg.loss), "data_fraction": cfg.data.fraction,
              "layers": cfg.model.pose.layers, "dim": cfg.model.pose.dim, "heads": cfg.model.pose.heads,
              "ff": cfg.model.pose.ff, **numbers(cfg)}
    loop.check_resume(run_dir, {**record, "train": to_dict(cfg.train)}, ("model", "data", "aug", "loss", "train"))
    run_dir.mkdir(parents=True, exist_ok=True)
    norm.save(run_dir)

    def get_batch(idx):
        c, s = np.asarray(idx) // starts, np.asarray(idx) % starts
        return {"H": H[c[:, None], s[:, None] + np.arange(2 * t)]}

    val = np.asarray(ds.split("val"))[:64]
    val_x = np.asarray(ds.motion[val], np.float32) if len(val) else None

    def evaluate(params, ema, step):
        if val_x is None:
            return {}
        e = span_errors_mm(ema or params, cfg.model, norm, val_x)
        return {f"eval/{k}": v for k, v in e.items()}

    return loop.train(run_dir, loop.TrainSpec(
        init=lambda rng: G.init_pose(rng, cfg.model), loss=make_loss(cfg, norm), cfg=cfg.train, config=record,
        get_batch=get_batch, num_examples=len(clips) * starts, evaluate=evaluate,
        flops_per_sample=record["flops_per_sample"], resume_keys=("model", "data", "aug", "loss", "train")),
        stop_at=stop_at, on_log=on_log)


@dataclass
class PoseRun:
    run_dir: Path
    cfg: PoseRunConfig
    params: dict
    norm: C.Norm
    step: int
    tasks: tuple = ()  # a step, not a generator

    @property
    def fingerprint(self) -> str:
        """Hash of P's configuration, parameters and frame statistics (what an A run trained on it depends on)."""
        import hashlib
        import json

        h = hashlib.sha256(json.dumps(to_dict(self.cfg.model), sort_keys=True).encode())
        for leaf in [*jax.tree_util.tree_leaves(self.params), self.norm.mean, self.norm.std]:
            h.update(np.ascontiguousarray(np.asarray(leaf, np.float32)).tobytes())
        return h.hexdigest()[:16]

    def generate(self, prompts, opts, **kw):
        raise ValueError("a ghtt-pose run is the P block of a G-HTT run, not a generator: train "
                         "`handx train ghtt --ghtt-pose RUN` on it and generate with that run")

    def generate_long(self, segments, opts, **kw):
        return self.generate(segments, opts)

    def describe(self, opts) -> str:
        return f"G-HTT P block at step {self.step}"


def load(run_dir, *, ema: bool = True, encoder=None, overrides: Sequence[str] = ()) -> PoseRun:
    from handx_jax.train import load_params

    doc = run_config(run_dir, FAMILY)
    cfg = from_dict(PoseRunConfig, doc)
    params, step = load_params(run_dir, ema=ema)
    return PoseRun(Path(run_dir), cfg, params, C.Norm.load(run_dir), step)


# ------------------------------------------------------------------------------------------------
# Command-line hooks


def add_train_args(p) -> None:
    p.add_argument("--data", required=True, help="dataset directory")


def config_from_args(args) -> PoseRunConfig:
    return make_config(args.preset, args.set, data=args.data)


def add_params_args(p) -> None:
    pass


def params_from_args(args):
    cfg = make_config(args.preset, args.set)
    b = cfg.model.pose
    return f"ghtt-pose {cfg.preset}: L{b.layers}+{b.layers} d{b.dim} H{b.heads} FF{b.ff}, span {cfg.model.span}", numbers(cfg)


def add_generate_args(p) -> None:
    pass


def load_for_generate(args: argparse.Namespace, *, ema, encoder, seed, batch_size):
    return load(args.run, ema=ema), None
