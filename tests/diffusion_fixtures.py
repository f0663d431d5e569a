"""Shared tiny fixtures for the diffusion-family tests: a 32-clip corpus with a per-field text cache
(the gated tiny T5 fixture) and a few-step tiny run."""

from __future__ import annotations

import fcntl
import functools
import os
import shutil
import types
from pathlib import Path

ENCODER = Path(__file__).parent / "fixtures" / "t5_tiny_gated"


def _build(root: Path, joined: bool) -> Path:
    from handx_jax.dataset.build import BuildConfig, build_corpus
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


# The session's tiny diffusion run: 4 steps (test_generate.py's measured contact-guidance figures are this
# model's), a checkpoint every 2 and a metrics row every step (test_diffusion_train.py kills a copy of it after
# step 3 and resumes). Checkpoints and logging do not change the trained numbers.
RUN_OVERRIDES = ("train.steps=4", "train.ckpt_every=2", "train.log_every=1")


def make_run(root: Path) -> tuple[Path, Path]:
    """The 32-clip corpus (per-field cache) under ``root/ds`` and a tiny run trained on it with
    ``tiny_config(data, *RUN_OVERRIDES)`` under ``root/run``: built once per test session in the session
    folder, under a file lock, and copied (tests write into the run folder: ``handx eval prediction``'s
    results). The run's config.json names the session's copy of the corpus, the same bytes as ``root/ds``."""
    from handx_jax.families.diffusion import train

    session = os.environ.get("HANDX_TEST_SESSION")
    if not session:
        data = make_dataset(root)
        train(root / "run", tiny_config(data, *RUN_OVERRIDES))
        return data, root / "run"
    shared = Path(session) / "shared" / "tinyrun4"
    shared.parent.mkdir(parents=True, exist_ok=True)
    with open(shared.parent / ".tinyrun.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (shared / "done").exists():
            shutil.rmtree(shared, ignore_errors=True)
            train(shared / "run", tiny_config(make_dataset(shared), *RUN_OVERRIDES))
            (shared / "done").touch()
    shutil.copytree(shared / "ds", root / "ds")
    shutil.copytree(shared / "run", root / "run")
    return root / "ds", root / "run"


@functools.lru_cache(maxsize=None)
def tiny_denoiser():
    """The tiny preset's denoiser with dropout 0 (its training path then computes what the forward-only path
    computes), params from PRNGKey(0), and its paths jitted with every array an argument: one process compiles
    each path once for every test that calls it, and tests in other processes load it from the session's
    compilation cache (same program, same name). Returns (cfg, model, params, programs)."""
    import dataclasses

    import jax

    from handx_jax.models.dit import PRESETS, init_denoiser

    cfg = dataclasses.replace(PRESETS["tiny"], dropout=0.0)
    model, params = init_denoiser(cfg, jax.random.PRNGKey(0), 8)
    programs = types.SimpleNamespace(
        encode=jax.jit(lambda p, text, mask: model.apply(p, text, mask, method=model.encode)),
        full=jax.jit(lambda p, x, t, text, mask, drop, det: model.apply(p, x, t, text, mask, drop, deterministic=det),
                     static_argnums=6),
        denoise=jax.jit(lambda p, x, t, memory, null_rows, repeats: model.apply(
            p, x, t, memory, null_rows, repeats, method=model.denoise), static_argnums=(4, 5)))
    return cfg, model, params, programs


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
