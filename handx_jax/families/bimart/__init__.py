"""BimArt (Zhang et al., "A Unified Approach for the Synthesis of 3D Bimanual Interaction with Articulated
Objects"): two hands generated for a given articulated object and its trajectory (task ``object2motion``).

    handx data objects --clips 2000 --out OBJ
    handx train bimart-contact --data OBJ --preset tiny --out CONTACT           # §3.2, the contact generator
    handx train bimart --data OBJ --bimart-contact CONTACT --preset tiny --out RUN
    handx generate --run RUN --task object2motion --data OBJ --clip 3 --out gen.npz
    handx eval objects --generated gen.npz                                       # Pen, Con, Art, Mul, ...

Why two runs: the contact model is trained alone (§3.2) and one serves every motion run trained on it, so it is
a shared step the registry names (``Family.needs``), as G-HTT's pose block is.

Training (§3.3): X = [H | D] per frame (common.py), normalised per channel over the train split; a DDPM (50 steps,
x0-prediction, MSE) whose denoiser reads the object embedding Z_o and the contact embedding Z_c of the clip's
ground-truth contact maps, Z_c replaced by the learned null token with probability p_f = 0.5 (§3.5).

Sampling (one jitted program, ``run.sample_motion``): contact maps Ĉ from the contact run; then the motion DDPM
with classifier-free guidance x̂0 = (1 + λ_f) c - λ_f u, λ_f = 0.5 (§3.5; Eq. 7 prints the unconditional term
without its λ_f, which would not be a guidance of a normalised prediction), and contact guidance (Eq. 6,
physics.py) of strength s (1 = BimArt's unit step) at every step, applied to the conditional prediction c before
CFG (``sample.guide_at=before_cfg``, BimArt's code) or to the guided x̂0 (``after_cfg``, this project's diffusion
family's place for it). Then refinement (§3.4, physics.refine), one jitted optimisation per batch.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import jax
import jax.numpy as jnp

from handx_jax.config import ConfigError, to_dict
from handx_jax.families.bimart import common as C
from handx_jax.families.bimart import contact as CM
from handx_jax.models import bimart as BM

# The run configuration and the loaded run have their own modules; the family's names are these:
from handx_jax.families.bimart.config import (CONTACTS, FAMILY, KIND, PRESETS, TASKS, Config,  # noqa: F401
                                              DataConfig, MotionRunConfig, SampleConfig, make_config)
from handx_jax.families.bimart.run import BimArtRun, GenerateOptions, load  # noqa: F401


def numbers(cfg: MotionRunConfig, **kw) -> dict:
    n = BM.param_count(cfg.model, KIND)
    return {"params": n["params"], "params_non_embedding": n["params_non_embedding"],
            "flops_per_sample": BM.forward_flops(cfg.model, KIND), "text_flops_per_sample": 0}


def make_loss(cfg: MotionRunConfig, sched):
    m = cfg.model

    def loss(params, batch, rng, train: bool):
        k_drop, k_diff = jax.random.split(rng)
        B = batch["x"].shape[0]
        null = jax.random.bernoulli(k_drop, cfg.p_drop, (B,)) if train else jnp.zeros((B,), bool)
        l = C.diffusion_loss(lambda x, t: BM.denoise(params, m, x, t, batch["obj"], batch["contact"], null),
                             sched, batch["x"], k_diff)
        return l, {"mse": l}

    return loss


def train(run_dir: str | os.PathLike, cfg: MotionRunConfig, *, stop_at=None, on_log=None, encoder=None) -> dict:
    from handx_jax import train as loop

    cfg.validate()
    for key in ("path", "contact"):
        if not getattr(cfg.data, key):
            raise ConfigError(f"data.{key} is empty: give --data and --bimart-contact")
    contact = CM.load(cfg.data.contact)
    clips = C.train_clips(cfg.data.path, cfg.data.fraction)
    data = C.prepare(cfg.data.path, clips, cfg.model, motion=True)
    norm = C.Norm.fit(data.motion)
    x = (data.motion - norm.mean) / norm.std
    run_dir = Path(run_dir)
    m = cfg.model
    record = {"family": FAMILY, "preset": cfg.preset, "model": to_dict(m), "data": to_dict(cfg.data),
              "p_drop": cfg.p_drop, "sample": to_dict(cfg.sample), "data_fraction": cfg.data.fraction,
              "layers": m.block.layers, "dim": m.block.dim, "heads": m.block.heads, "ff": m.block.ff,
              **numbers(cfg),
              "contact_run": {"path": cfg.data.contact, "step": contact.step, "fingerprint": contact.fingerprint,
                              "train_flops": _train_flops(cfg.data.contact)}}
    keys = ("model", "data", "p_drop", "train", "contact_run")
    loop.check_resume(run_dir, {**record, "train": to_dict(cfg.train)}, keys)
    run_dir.mkdir(parents=True, exist_ok=True)
    norm.save(run_dir)
    return loop.train(run_dir, loop.TrainSpec(
        init=lambda rng: BM.init(rng, m, KIND), loss=make_loss(cfg, C.schedule(m)), cfg=cfg.train, config=record,
        get_batch=lambda idx: {"x": x[idx], "obj": data.obj[idx], "contact": data.contact[idx]},
        num_examples=len(clips), flops_per_sample=record["flops_per_sample"], resume_keys=keys),
        stop_at=stop_at, on_log=on_log)


def _train_flops(run_dir) -> float | None:
    from handx_jax.infra.readers import read_jsonl

    p = Path(run_dir) / "metrics.jsonl"
    rows = [r for r in read_jsonl(p, strict=False) if isinstance(r, dict) and r.get("train_flops")] if p.exists() else []
    return float(rows[-1]["train_flops"]) if rows else None


# ------------------------------------------------------------------------------------------------
# Command-line hooks


def add_train_args(p) -> None:
    p.add_argument("--data", required=True, help="dataset: a hand-object corpus (handx data objects)")
    p.add_argument("--bimart-contact", required=True, metavar="CONTACT",
                   help="the trained contact generator (`handx train bimart-contact`)")


def config_from_args(args) -> MotionRunConfig:
    return make_config(args.preset, args.set, data=args.data, contact=args.bimart_contact)


def add_params_args(p) -> None:
    pass


def params_from_args(args):
    cfg = make_config(args.preset, args.set)
    b, m = cfg.model.block, cfg.model
    return (f"bimart {cfg.preset}: L{b.layers} d{b.dim} H{b.heads} FF{b.ff}, K {m.k}, J {m.keypoints}, "
            f"{m.steps} steps", numbers(cfg))


def add_generate_args(p) -> None:
    p.add_argument("--contact", choices=CONTACTS, help="contact condition: generated (default), ground_truth, none")
    p.add_argument("--guidance", type=float, help="contact guidance strength s (0: off; default the run's, 1)")
    p.add_argument("--no-refine", action="store_true", help="skip the refinement (§3.4)")


def load_for_generate(args: argparse.Namespace, *, ema: bool, encoder, seed: int, batch_size: int):
    run = load(args.run, ema=ema, overrides=args.set)
    s = run.cfg.sample
    return run, GenerateOptions(contact=args.contact or s.contact, guidance=s.guidance if args.guidance is None
                                else args.guidance, refine=s.refine and not args.no_refine, seed=seed,
                                batch_size=batch_size)
