"""Shared tiny fixtures for the diffusion-family tests: a 32-clip corpus with a per-field text cache
(the gated tiny T5 fixture) and a few-step tiny run."""

from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path

ENCODER = Path(__file__).parent / "fixtures" / "t5_tiny_gated"


def _build(root: Path, joined: bool) -> Path:
    from handx_jax.data.build import BuildConfig, build_corpus
    from handx_jax.text.cache import build_cache

    data = build_corpus(root / "ds", BuildConfig(clips=32, seed=3, workers=1, val_fraction=0.2, test_fraction=0.2),
                        progress=False)
    build_cache(data, ENCODER, joined=joined, log=lambda s: None)
    return data


def make_dataset(root: Path, joined: bool = False) -> Path:
    """The 32-clip corpus (seed 3) with its per-field (or ``joined``) text cache, under ``root/ds``.

    Built once per test session in the session folder (tests/conftest.py) and copied from there: several
    test files use this same corpus, and the copy costs milliseconds where the build costs seconds. The
    build runs under a file lock, so two xdist workers never build it twice or read it half-written."""
    session = os.environ.get("HANDX_TEST_SESSION")
    if not session:
        return _build(root, joined)
    shared = Path(session) / "shared" / f"corpus32-seed3-{'joined' if joined else 'fields'}"
    shared.parent.mkdir(parents=True, exist_ok=True)
    with open(shared.parent / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (shared / "done").exists():
            shutil.rmtree(shared, ignore_errors=True)
            _build(shared, joined)
            (shared / "done").touch()
    shutil.copytree(shared / "ds", root / "ds")
    return root / "ds"


def tiny_config(data: Path, *overrides: str):
    from handx_jax.families.diffusion import make_config

    base = ("train.steps=6", "train.batch_size=8", "train.log_every=2", "train.ckpt_every=3", "train.wandb=disabled",
            "train.optim.warmup_steps=0", "train.optim.lr=1e-3")
    return make_config("tiny", base + overrides, data=str(data), encoder=str(ENCODER))


def make_evaluator(dst: Path) -> Path:
    """A tiny evaluator (10 steps) of the joined 32-clip corpus, built once per test session and copied
    to ``dst``: enough for a sweep's evaluate stage to score generated motion (not to rank it well)."""
    from handx_jax.evaluation import make_evaluator_config, train_evaluator

    session = os.environ.get("HANDX_TEST_SESSION")
    shared = Path(session) / "shared" / "evaluator10" if session else dst.parent / "evaluator10"
    shared.parent.mkdir(parents=True, exist_ok=True)
    with open(shared.parent / ".evaluator.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (shared / "done").exists():
            shutil.rmtree(shared, ignore_errors=True)
            data = make_dataset(shared, joined=True)
            cfg = make_evaluator_config("tiny", ("train.steps=10", "train.batch_size=8", "train.optim.lr=1e-3",
                                                 "train.optim.warmup_steps=0", "train.log_every=5",
                                                 "train.wandb=disabled", "text.max_len=64", "text.train_levels=none",
                                                 "text.eval_level=0", "final_eval=false"),
                                        data=str(data), encoder=str(ENCODER))
            train_evaluator(shared / "E", cfg, log=lambda s: None)
            (shared / "done").touch()
    shutil.copytree(shared / "E", dst)
    return dst
