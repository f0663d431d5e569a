"""A run of the one training loop (handx_jax.train.train) with an evaluation hook, for the kill -9 test of
tests/test_bad_input_train.py:

    python tests/train_kill_worker.py RUN_DIR

A linear fit, a training row every step, the hook's row at step 0 (as every family's: G-HTT's recognition,
the tokenizer's reconstruction) and a checkpoint only at the end, so a kill lands before the first
checkpoint. Each batch waits 50 ms, so the run is still going when the test kills it. The test resumes the
same run in its own process through :func:`run`.
"""

import sys
import time

import jax.numpy as jnp
import numpy as np

from handx_jax.optim import OptimConfig
from handx_jax.train import TrainConfig, TrainSpec, train

X = np.random.default_rng(0).normal(size=(32, 3)).astype(np.float32)
Y = X @ np.asarray([1.0, -2.0, 0.5], np.float32)
CFG = TrainConfig(steps=10_000, batch_size=8, log_every=1, ckpt_every=10_000, wandb="disabled", prefetch=0,
                  optim=OptimConfig(lr=1e-2, warmup_steps=0))


def batch(idx):
    time.sleep(0.05)
    return {"x": X[idx], "y": Y[idx]}


def loss(params, b, rng, train_mode):
    return jnp.mean((b["x"] @ params["w"] - b["y"]) ** 2), {}


def evaluate(params, ema, step):
    return {"eval/mse": float(jnp.mean((X @ params["w"] - Y) ** 2))}


def run(run_dir, stop_at=None) -> dict:
    spec = TrainSpec(init=lambda key: {"w": jnp.zeros(3)}, loss=loss, cfg=CFG, config={"family": "kill-test"},
                     get_batch=batch, num_examples=len(X), evaluate=evaluate)
    return train(run_dir, spec, stop_at=stop_at)


if __name__ == "__main__":
    run(sys.argv[1])
