"""The sweep launcher: one function per run, run locally or on SLURM, resumable, results as a table.

A sweep is a plain Python file with ``def runs(**kw) -> list[RunSpec]`` (see
``sweeps/diffusion_scaling.py``). Each run goes through three idempotent stages, each a ``handx``
subprocess so that one run's crash or memory never takes the sweep down:

    train     handx train <family> --preset P --set ... --out RUN      (resumes from RUN/checkpoints)
    generate  handx generate --run RUN --reference DATA --split test --limit N --out RUN/generated.npz
    evaluate  handx eval run --evaluator E --generated RUN/generated.npz --reference DATA --json --out RUN/eval.json

A stage is done when its output exists (every output is written atomically), so a killed sweep
re-run with the same command picks up exactly where it stopped. After every run the results table
``OUT/results.jsonl`` is rebuilt from all run folders (``analysis.schema.row_from_run_dir``), which
is what ``handx analyze`` reads. wandb groups the runs under the sweep's name (WANDB_RUN_GROUP).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from handx_jax.io import atomic_write_json, atomic_write_jsonl


@dataclass(frozen=True)
class RunSpec:
    """One point of a sweep: a family, a size preset and dotted config overrides."""

    name: str
    family: str = "diffusion"
    preset: str = "tiny"
    overrides: tuple[str, ...] = ()


@dataclass(frozen=True)
class SweepConfig:
    data: str
    encoder: str
    out: str
    evaluator: str | None = None  # without one, runs are trained (and generate) but not scored
    eval_split: str = "test"
    eval_limit: int = 512
    eval_samples: int = 1
    sampler: str = "ddim"
    sampler_steps: int = 50
    executor: str = "local"  # local | slurm | debug (submitit's in-process executor, for tests)
    slurm: dict = field(default_factory=dict)  # submitit parameters, e.g. {"slurm_partition": "gpu", "timeout_min": 600}
    name: str = ""


def load_sweep(path: str | os.PathLike, **kwargs) -> list[RunSpec]:
    """Import a sweep file and call its ``runs(**kwargs)``."""
    path = Path(path)
    spec = importlib.util.spec_from_file_location(f"handx_sweep_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise FileNotFoundError(f"cannot import sweep file {path}")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    if not hasattr(mod, "runs"):
        raise AttributeError(f"{path} defines no runs(**kw) function")
    specs = mod.runs(**kwargs)
    names = [s.name for s in specs]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ValueError(f"{path}: run names must be unique; repeated: {sorted(dup)}")
    return specs


def _handx(*args: str, env: dict | None = None) -> None:
    cmd = [sys.executable, "-m", "handx_jax", *args]
    r = subprocess.run(cmd, env={**os.environ, **(env or {})})
    if r.returncode != 0:
        raise RuntimeError(f"command failed ({r.returncode}): {' '.join(cmd)}")


def run_dir(cfg: SweepConfig, spec: RunSpec) -> Path:
    return Path(cfg.out) / "runs" / spec.name


def stage_state(cfg: SweepConfig, spec: RunSpec) -> dict[str, bool]:
    d = run_dir(cfg, spec)
    done = d / "train_done.json"
    return {"train": done.exists(), "generate": (d / "generated.npz").exists(), "evaluate": (d / "eval.json").exists()}


def run_one(spec: RunSpec, cfg: SweepConfig) -> dict[str, bool]:
    """Bring one run through its stages; each stage is skipped if its output already exists."""
    d = run_dir(cfg, spec)
    d.mkdir(parents=True, exist_ok=True)
    env = {"WANDB_RUN_GROUP": cfg.name or Path(cfg.out).name}
    state = stage_state(cfg, spec)
    if not state["train"]:
        sets = [a for o in spec.overrides for a in ("--set", o)]
        _handx("train", spec.family, "--data", cfg.data, "--encoder", cfg.encoder, "--preset", spec.preset,
               *sets, "--out", str(d), "--quiet", env=env)
        atomic_write_json(d / "train_done.json", {"spec": dataclasses.asdict(spec)})
    if cfg.evaluator:
        if not state["generate"]:
            # Prompt at the caption level the evaluator scores (its text policy), so that the
            # generated file's captions are the ones the evaluator embeds.
            level = json.loads((Path(cfg.evaluator) / "evaluator.json").read_text())["text"]["eval_level"]
            _handx("generate", "--run", str(d), "--reference", cfg.data, "--split", cfg.eval_split, "--level", str(level),
                   "--limit", str(cfg.eval_limit), "--samples", str(cfg.eval_samples), "--sampler", cfg.sampler,
                   "--steps", str(cfg.sampler_steps), "--out", str(d / "generated.npz"), env=env)
        if not state["evaluate"]:
            _handx("eval", "run", "--evaluator", cfg.evaluator, "--generated", str(d / "generated.npz"),
                   "--reference", cfg.data, "--json", "--out", str(d), env=env)
    collect_results(cfg.out)
    return stage_state(cfg, spec)


def collect_results(out: str | os.PathLike) -> Path:
    """Rebuild OUT/results.jsonl from every run folder that finished training."""
    from analysis.schema import row_from_run_dir

    out = Path(out)
    dirs = sorted((out / "runs").glob("*"))
    if (out / "sweep.json").exists():  # keep the sweep file's order (e.g. by size), not the folder names'
        order = {r["name"]: i for i, r in enumerate(json.loads((out / "sweep.json").read_text())["runs"])}
        dirs.sort(key=lambda d: (order.get(d.name, len(order)), d.name))
    rows = [row_from_run_dir(d) for d in dirs if (d / "train_done.json").exists()]
    path = out / "results.jsonl"
    atomic_write_jsonl(path, rows)
    return path


class _Job:
    """A picklable callable for submitit; requeued jobs simply call run_one again (it resumes)."""

    def __init__(self, spec: RunSpec, cfg: SweepConfig):
        self.spec, self.cfg = spec, cfg

    def __call__(self):
        return run_one(self.spec, self.cfg)

    def checkpoint(self, *args, **kwargs):  # submitit's preemption/timeout hook
        import submitit

        return submitit.helpers.DelayedSubmission(_Job(self.spec, self.cfg))


def launch(specs: Sequence[RunSpec], cfg: SweepConfig) -> Path:
    """Run every spec (skipping finished stages) and return the results table path."""
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "sweep.json", {"config": dataclasses.asdict(cfg),
                                           "runs": [dataclasses.asdict(s) for s in specs]})
    if cfg.executor == "local":
        for s in specs:
            print(f"== {s.name}: {s.family} {s.preset} {' '.join(s.overrides)}", flush=True)
            run_one(s, cfg)
    elif cfg.executor in ("slurm", "debug"):
        import submitit

        ex = submitit.AutoExecutor(folder=str(out / "submitit"), cluster=None if cfg.executor == "slurm" else "debug")
        ex.update_parameters(name=cfg.name or out.name, **cfg.slurm)
        if cfg.executor == "slurm":
            with ex.batch():  # one job array; each element keeps its checkpoint/requeue hook
                jobs = [ex.submit(_Job(s, cfg)) for s in specs]
        else:
            jobs = [ex.submit(_Job(s, cfg)) for s in specs]
        for j in jobs:
            j.result()
    else:
        raise ValueError(f"unknown executor {cfg.executor!r} (local | slurm | debug)")
    return collect_results(out)


def status(out: str | os.PathLike) -> list[dict]:
    out = Path(out)
    doc = json.loads((out / "sweep.json").read_text())
    cfg = SweepConfig(**doc["config"])
    rows = []
    for s in doc["runs"]:
        spec = RunSpec(**{**s, "overrides": tuple(s["overrides"])})
        rows.append({"name": spec.name, **stage_state(cfg, spec)})
    return rows
