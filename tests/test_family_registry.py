"""A throwaway third family, registered for one test only: it trains, generates, runs in a sweep and lands
in the results table with no edit outside this module and its registry line (issue 30 item 1).

The family is a mean pose: one (60, 42, 4) parameter fitted to the normalised diffusion features of the
train clips by the shared training loop, generated for every prompt. What it needs from the rest of the
system is what its ``REGISTRY`` entry declares (the dataset statistics it normalises with; no text encoder).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from handx_jax.families import Family
from handx_jax.train import TrainConfig

# The registry line (registered for the test's duration: handx_jax.families.register; the module by its
# import path from the repository root, which the launcher's stages have on PYTHONPATH).
REGISTRY = Family(module="tests.test_family_registry", help="a mean-pose toy family (tests only)",
                  norm="handx_jax.representation.diffusion:DIFFUSION_NORM")

FAMILY = "toy"
PRESETS = {"tiny": None}


@dataclass(frozen=True)
class DataConfig:
    path: str = ""
    fraction: float = 1.0


@dataclass(frozen=True)
class ToyConfig:
    preset: str = "tiny"
    train: TrainConfig = TrainConfig(steps=30, batch_size=8, log_every=10, ckpt_every=30, wandb="disabled")
    data: DataConfig = field(default_factory=DataConfig)

    def validate(self) -> None:
        pass


Config = ToyConfig


def make_config(preset: str = "tiny", overrides=(), *, data: str = "") -> ToyConfig:
    from handx_jax.config import apply_overrides

    return apply_overrides(ToyConfig(data=DataConfig(path=str(Path(data).absolute()) if data else "")), overrides)


def numbers(cfg: ToyConfig, **kw) -> dict:
    n = 60 * 42 * 4
    return {"params": n, "params_non_embedding": n, "flops_per_sample": 2.0 * n, "text_flops_per_sample": 0.0}


def train(run_dir, cfg: ToyConfig, *, stop_at=None, on_log=None, encoder=None) -> dict:
    import jax.numpy as jnp

    from handx_jax import representation as rep
    from handx_jax import train as loop
    from handx_jax.config import to_dict
    from handx_jax.dataset.format import Dataset

    ds = Dataset.open(cfg.data.path)
    norm = rep.NormStats.from_npz_dict(ds.stats, REGISTRY.norm_preset().name)
    clips = np.asarray(ds.split("train", cfg.data.fraction))
    x = norm.normalize(rep.to_diffusion(np.asarray(ds.motion[clips], np.float64))).astype(np.float32)
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    np.savez(Path(run_dir) / "norm.npz", **norm.to_npz_dict(REGISTRY.norm_preset().name))
    record = {"family": FAMILY, "preset": cfg.preset, "data": to_dict(cfg.data), "data_fraction": cfg.data.fraction,
              **numbers(cfg)}

    def loss(params, batch, rng, train):
        return jnp.mean((batch["x"] - params["mean"]) ** 2), {}

    return loop.train(run_dir, loop.TrainSpec(
        init=lambda rng: {"mean": jnp.ones((60, 42, 4))}, loss=loss, cfg=cfg.train, config=record,
        get_batch=lambda idx: {"x": x[np.asarray(idx)]}, num_examples=len(x),
        flops_per_sample=record["flops_per_sample"], resume_keys=("data", "train")), stop_at=stop_at, on_log=on_log)


@dataclass
class ToyRun:
    mean_Fx42x4: np.ndarray  # de-normalised
    step: int
    tasks: tuple = ("text2motion",)

    def generate(self, prompts, opts, *, samples=1, task="text2motion", sources=None, keyframes=(30,),
                 fixed_hand="left"):
        from handx_jax import representation as rep

        j = rep.diffusion_to_joints(self.mean_Fx42x4)
        return np.broadcast_to(j, (len(prompts), samples, *j.shape)).copy()

    def generate_long(self, segments, opts, *, samples=1, source=None):
        raise ValueError("the toy family does not do --task long")

    def describe(self, opts) -> str:
        return f"the mean pose at step {self.step}"


def load(run_dir, *, ema=True, encoder=None, overrides=()) -> ToyRun:
    from handx_jax import representation as rep
    from handx_jax.families import run_config
    from handx_jax.train import load_params

    run_config(run_dir, FAMILY)
    params, step = load_params(run_dir)
    with np.load(Path(run_dir) / "norm.npz") as z:
        norm = rep.NormStats.from_npz_dict(dict(z), REGISTRY.norm_preset().name)
    return ToyRun(norm.denormalize(np.asarray(params["mean"])), step)


def add_train_args(p) -> None:
    p.add_argument("--data", required=True)


def config_from_args(args) -> ToyConfig:
    return make_config(args.preset, args.set, data=args.data)


def add_params_args(p) -> None:
    pass


def params_from_args(args):
    return "toy", numbers(make_config(args.preset, args.set))


def add_generate_args(p) -> None:
    pass


def load_for_generate(args, *, ema, encoder, seed, batch_size):
    return load(args.run, overrides=args.set), None


# ------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_third_family_trains_generates_runs_in_a_sweep_and_lands_in_the_table(tmp_path):
    from analysis.schema import validate_row
    from analysis.tables import render_table
    from diffusion_fixtures import make_dataset, make_evaluator
    from handx_jax import representation as rep
    from handx_jax.dataset.format import Dataset
    from handx_jax.interop.handx_npz import read_handx_npz
    from handx_jax.families import register
    from handx_jax.infra.errors import DataError
    from sweeps.launcher import RunSpec, SweepConfig, launch

    data = make_dataset(tmp_path, joined=True)
    E = make_evaluator(tmp_path / "E")
    with register("toy", REGISTRY):
        # One run: each run of a sweep is three CLI processes (train, generate, evaluate).
        specs = [RunSpec("toy-30", "toy", overrides=("train.steps=30", "train.optim.lr=0.1",
                                                     "train.optim.warmup_steps=0"), axes={"steps": 30})]
        cfg = SweepConfig(data=str(data), encoder="", out=str(tmp_path / "sweep"), evaluator=str(E), eval_limit=4,
                          rprec_block=4)
        res = launch(specs, cfg)
        assert not res.failed, res.failed
        rows = [json.loads(x) for x in Path(res.results).read_text().splitlines()]
        assert [(r["family"], r["status"]) for r in rows] == [("toy", "done")]
        assert all(r["rprec_top3"] is not None and r["params"] == 60 * 42 * 4 for r in rows)
        # trained: the run's mean pose is closer to the train clips' mean than its initial one (the parameter
        # starts at ones in normalised units, de-normalised with the run's own statistics)
        ds = Dataset.open(data)
        train_mean = rep.to_diffusion(np.asarray(ds.motion[np.asarray(ds.split("train"))], np.float64)).mean(0)
        run_dir = tmp_path / "sweep" / "runs" / "toy-30"
        with np.load(run_dir / "norm.npz") as z:
            init = rep.NormStats.from_npz_dict(dict(z), REGISTRY.norm_preset().name).denormalize(np.ones((60, 42, 4)))
        run = load(run_dir)
        assert run.step == 30
        assert np.abs(run.mean_Fx42x4 - train_mean).mean() < 0.5 * np.abs(init - train_mean).mean()
        # generated: every sample of every prompt is that mean pose, in the official layout
        clips = read_handx_npz(tmp_path / "sweep" / "runs" / "toy-30" / "generated.npz")
        want = rep.diffusion_to_joints(run.mean_Fx42x4)
        assert len(clips) == 4 and all(np.allclose(c.motion, want, atol=1e-5) for c in clips)
        table = render_table(rows, "csv")
        lines = table.splitlines()
        assert lines[0].startswith("run_id,family") and "rprec_top3" in lines[0]
        assert [ln.split(",")[:2] for ln in lines[1:]] == [["toy-30", "toy"]]
    # Unregistered, the name is unknown again everywhere (the registry is the only place that names it).
    try:
        validate_row(rows[0])
        raise AssertionError("an unregistered family was accepted")
    except DataError as e:
        assert "unknown family 'toy'" in str(e)
