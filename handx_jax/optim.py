"""The optimiser every family trains with: AdamW, warm-up and schedule, clipping (``handx_jax.train``).

- AdamW with decoupled weight decay on parameters of ndim ≥ 2 only (reference §3.6), gradient clipping
  applied *before* the update (the reference clips after ``opt.step()``, §9.17).
- Linear warm-up and cosine/constant schedule as traced numbers (:func:`schedule_values`), so runs that
  differ only in those share one compiled step; a warm-up as long as the run or longer is capped at a
  fifth of it (:func:`effective_warmup`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax


@dataclass(frozen=True)
class OptimConfig:
    lr: float = 1e-4
    b1: float = 0.9
    b2: float = 0.95
    eps: float = 1e-8
    weight_decay: float = 5e-6
    warmup_steps: int = 0
    schedule: str = "constant"  # "constant" (reference) or "cosine" (decay to 0 at the last step)
    grad_clip: float = 1.0  # 0 disables

    def check_values(self, key: str = "train.optim") -> None:
        """Finite numbers in range (``config.validate``): a NaN learning rate would otherwise train until the
        first logged loss is NaN, with the run folder written."""
        from handx_jax.config import ConfigError
        from handx_jax.infra.values import check

        name = lambda n: f"{key}.{n}" if key else n  # noqa: E731
        for n in ("lr", "weight_decay", "grad_clip"):
            check(getattr(self, n), name(n), minimum=0)
        check(self.eps, name("eps"), above=0)
        for n in ("b1", "b2"):
            check(getattr(self, n), name(n), minimum=0, below=1)
        check(self.warmup_steps, name("warmup_steps"), whole=True, minimum=0)
        if self.schedule not in ("constant", "cosine"):
            raise ConfigError(f"{name('schedule')} must be constant or cosine, got {self.schedule!r}")



def effective_warmup(warmup_steps: int, total_steps: int) -> int:
    """The warm-up a run really uses: as configured, unless it is as long as the run or longer, when it is
    capped at a fifth of the run (the evaluator trainer's fraction, ``evaluation.training``).

    Capped rather than refused: a family's warm-up is set for its full-length recipe (the reference's
    8,000 tokenizer and 15,000 LM steps, §4.3/§4.7) and a sweep shortens the run with ``train.steps``
    alone; refusing would make every short run of every preset restate its warm-up, and uncapped, such a
    run never reaches its peak lr (issue 30: a 200-step tokenizer ended at lr 5e-6 of 2e-4). A warm-up
    shorter than the run is the user's choice and is kept."""
    if total_steps > 0 and warmup_steps >= total_steps:
        return max(total_steps // 5, 1)
    return warmup_steps


def schedule_values(cfg: OptimConfig, total_steps: int) -> np.ndarray:
    """The numbers of the learning-rate schedule, [peak lr, warm-up steps, decay end], as float32; the
    warm-up is :func:`effective_warmup` (capped when it would last the whole run).

    The train step takes them as a traced argument rather than baking them in as constants, so runs
    that differ only in learning rate, warm-up or length (a sweep's data-fraction axis at fixed epochs,
    a learning-rate scan, a resumed or extended run) share one compiled step, through the persistent
    compilation cache, instead of compiling it again each."""
    if cfg.schedule not in ("constant", "cosine"):
        raise ValueError(f"unknown schedule {cfg.schedule!r}")
    warmup = effective_warmup(cfg.warmup_steps, total_steps)
    if cfg.schedule == "cosine":
        return np.asarray([cfg.lr, max(warmup, 1), max(total_steps, 2, warmup + 1)], np.float32)
    return np.asarray([cfg.lr, warmup, max(total_steps, 1)], np.float32)


def learning_rate(count, values, schedule: str):
    """The learning rate at update ``count`` from :func:`schedule_values` (concrete or traced).

    Same values as optax's schedules: "constant" = linear 0 -> lr over the warm-up, then lr
    (``join_schedules([linear_schedule, constant_schedule])``); "cosine" =
    ``warmup_cosine_decay_schedule(0, lr, warmup, end)``, decaying to 0 at step ``end``."""
    lr, warmup, end = values[0], values[1], values[2]
    c = jnp.asarray(count, jnp.float32)
    ramp = lr * jnp.clip(c, 0.0, warmup) / jnp.maximum(warmup, 1.0)
    if schedule == "constant":
        return jnp.where(c < warmup, ramp, lr)
    frac = jnp.clip(c - warmup, 0.0, end - warmup) / (end - warmup)
    return jnp.where(c < warmup, ramp, lr * 0.5 * (1.0 + jnp.cos(jnp.pi * frac)))


def optimizer_for(cfg: OptimConfig, lr_fn: Callable) -> optax.GradientTransformation:
    """Global-norm clipping, then AdamW with ``lr_fn(count)`` and weight decay on matrices only."""
    decay_mask = lambda p: jax.tree_util.tree_map(lambda x: x.ndim >= 2, p)  # noqa: E731
    parts = [optax.clip_by_global_norm(cfg.grad_clip)] if cfg.grad_clip > 0 else []
    parts.append(optax.adamw(lr_fn, b1=cfg.b1, b2=cfg.b2, eps=cfg.eps, weight_decay=cfg.weight_decay,
                             mask=decay_mask))
    return optax.chain(*parts)
