"""BimArt's bimanual contact generator (§3.2, Eq. 4): the step a ``bimart`` run is trained from.

    handx data objects --clips 2000 --out OBJ
    handx train bimart-contact --data OBJ --preset tiny --out CONTACT
    handx train bimart --data OBJ --bimart-contact CONTACT --preset tiny --out RUN

A DDPM over per-frame contact maps of both hands over both parts' K basis-mapped points (the corpus's
``contact_map.npy``: the distance from each mapped point to the hand's surface), predicting x0 with a transformer
encoder over the frames, conditioned on the object features [O | G | s_o] through the MLP E_o
(models/bimart.py). A step, not a generator (``Family.tasks`` is empty): the motion run samples it inside its
own jitted loop (``sample_fn``).
"""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.config import ConfigError, apply_overrides, from_dict, get_preset, to_dict
from handx_jax.families import run_config
from handx_jax.families.bimart import common as C
from handx_jax.families.diffusion.process import DiffusionConfig, sample
from handx_jax.models import bimart as BM
from handx_jax.train import TrainConfig

FAMILY = "bimart-contact"
KIND = "contact"
PRESETS = BM.PRESETS


@dataclass(frozen=True)
class ContactRunConfig:
    preset: str = "tiny"
    model: BM.BimArtConfig = PRESETS["tiny"]
    train: TrainConfig = C.CPU_TRAIN
    data: C.DataConfig = field(default_factory=C.DataConfig)

    def validate(self) -> None:
        C.check_model(self.model)
        if not 0 < self.data.fraction <= 1:
            raise ConfigError(f"data.fraction must be in (0, 1], got {self.data.fraction}")


Config = ContactRunConfig


def make_config(preset: str = "tiny", overrides: Sequence[str] = (), *, data: str = "") -> ContactRunConfig:
    cfg = ContactRunConfig(preset=preset, model=get_preset(PRESETS, preset, "BimArt preset"),
                           train=C.TRAIN_PRESETS[preset], data=C.DataConfig(str(Path(data).absolute()) if data else ""))
    return apply_overrides(cfg, overrides)


def numbers(cfg: ContactRunConfig, **kw) -> dict:
    n = BM.param_count(cfg.model, KIND)
    return {"params": n["params"], "params_non_embedding": n["params_non_embedding"],
            "flops_per_sample": BM.forward_flops(cfg.model, KIND), "text_flops_per_sample": 0}


def sample_fn(params, cfg: BM.BimArtConfig, obj_BxFxO, key):
    """Contact maps (B, F, 4K) in metres, sampled by DDPM over all cfg.steps (traceable: callers jit it, alone or
    inside the motion sampler)."""
    B, F, _ = obj_BxFxO.shape

    def den(x, t_B, drop_B):
        del drop_B  # no classifier-free guidance in the contact model (§3.2)
        return BM.denoise(params, cfg, x, t_B, obj_BxFxO)

    u = sample(den, C.schedule(cfg), (B, F, BM.contact_dim(cfg)), key, DiffusionConfig(steps=cfg.steps),
               sampler="ddpm", guidance=1.0)
    return C.unit_to_contact(jnp.clip(u, -1.0, 1.0))


def contact_l1(params, cfg: BM.BimArtConfig, data: C.Clips, key) -> dict:
    """CM (§4): the mean |generated - ground truth| (cm) of sampled maps, beside two train-free references: the
    maps of the clips shifted by one (another clip's contacts) and a constant 'far' map."""
    gen = np.asarray(jax.jit(sample_fn, static_argnums=1)(params, cfg, jnp.asarray(data.obj), key))
    gt = np.asarray(C.unit_to_contact(jnp.asarray(data.contact)))
    return {"cm_cm": float(100 * np.abs(gen - gt).mean()),
            "cm_other_clip_cm": float(100 * np.abs(np.roll(gt, 1, 0) - gt).mean()) if len(gt) > 1 else float("nan"),
            "cm_far_cm": float(100 * np.abs(C.CONTACT_MAX_M - gt).mean())}


def train(run_dir: str | os.PathLike, cfg: ContactRunConfig, *, stop_at=None, on_log=None, encoder=None) -> dict:
    from handx_jax import train as loop
    from handx_jax.dataset.format import Dataset

    cfg.validate()
    if not cfg.data.path:
        raise ConfigError("data.path is empty: give --data")
    clips = C.train_clips(cfg.data.path, cfg.data.fraction)
    data = C.prepare(cfg.data.path, clips, cfg.model, motion=False)
    sched = C.schedule(cfg.model)
    m = cfg.model
    record = {"family": FAMILY, "preset": cfg.preset, "model": to_dict(m), "data": to_dict(cfg.data),
              "data_fraction": cfg.data.fraction, "layers": m.block.layers, "dim": m.block.dim,
              "heads": m.block.heads, "ff": m.block.ff, **numbers(cfg)}
    keys = ("model", "data", "train")
    loop.check_resume(Path(run_dir), {**record, "train": to_dict(cfg.train)}, keys)

    def loss(params, batch, rng, train: bool):
        l = C.diffusion_loss(lambda x, t: BM.denoise(params, m, x, t, batch["obj"]), sched, batch["x"], rng)
        return l, {"mse": l}

    val = np.asarray(Dataset.open(cfg.data.path).split("val"))[:32]
    vdata = C.prepare(cfg.data.path, val, m, motion=False) if len(val) else None

    def evaluate(params, ema, step):
        return {} if vdata is None else {f"eval/{k}": v for k, v in
                                         contact_l1(ema or params, m, vdata, jax.random.PRNGKey(0)).items()}

    return loop.train(Path(run_dir), loop.TrainSpec(
        init=lambda rng: BM.init(rng, m, KIND), loss=loss, cfg=cfg.train, config=record,
        get_batch=lambda idx: {"obj": data.obj[idx], "x": data.contact[idx]}, num_examples=len(clips),
        evaluate=evaluate, flops_per_sample=record["flops_per_sample"], resume_keys=keys),
        stop_at=stop_at, on_log=on_log)


@dataclass
class ContactRun:
    run_dir: Path
    cfg: ContactRunConfig
    params: dict
    step: int
    tasks: tuple = ()  # a step, not a generator

    model_doc: dict | None = None  # config.json's "model" as recorded (what the fingerprint hashes)

    @property
    def fingerprint(self) -> str:
        """Hash of the recorded model configuration and the parameters (what a motion run trained on it depends
        on). The recorded dict, not today's dataclass: a config field added later with its default must not
        change the fingerprint of a run trained before it."""
        import hashlib
        import json

        doc = self.model_doc if self.model_doc is not None else to_dict(self.cfg.model)
        h = hashlib.sha256(json.dumps(doc, sort_keys=True).encode())
        for leaf in jax.tree_util.tree_leaves(self.params):
            h.update(np.ascontiguousarray(np.asarray(leaf, np.float32)).tobytes())
        return h.hexdigest()[:16]

    def generate(self, prompts, opts, **kw):
        raise ValueError("a bimart-contact run is the contact generator of a BimArt run, not a generator of motion: "
                         "train `handx train bimart --bimart-contact RUN` on it and generate with that run")

    def generate_long(self, segments, opts, **kw):
        return self.generate(segments, opts)

    def describe(self, opts) -> str:
        return f"BimArt contact generator at step {self.step}"


def load(run_dir, *, ema: bool = True, encoder=None, overrides: Sequence[str] = ()) -> ContactRun:
    from handx_jax.train import load_params

    doc = run_config(run_dir, FAMILY)
    cfg = from_dict(ContactRunConfig, doc)
    params, step = load_params(run_dir, ema=ema)
    return ContactRun(Path(run_dir), cfg, params, step, model_doc=doc.get("model"))


# ------------------------------------------------------------------------------------------------
# Command-line hooks


def add_train_args(p) -> None:
    p.add_argument("--data", required=True, help="dataset: a hand-object corpus (handx data objects)")


def config_from_args(args) -> ContactRunConfig:
    return make_config(args.preset, args.set, data=args.data)


def add_params_args(p) -> None:
    pass


def params_from_args(args):
    cfg = make_config(args.preset, args.set)
    b = cfg.model.block
    return f"bimart-contact {cfg.preset}: L{b.layers} d{b.dim} H{b.heads} FF{b.ff}, K {cfg.model.k}", numbers(cfg)


def add_generate_args(p) -> None:
    pass


def load_for_generate(args: argparse.Namespace, *, ema, encoder, seed, batch_size):
    return load(args.run, ema=ema), None
