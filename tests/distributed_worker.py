"""One process of the data-parallel training test (tests/test_distributed.py).

    python tests/distributed_worker.py RUN_DIR

Calls ``handx_jax.train.initialize_distributed`` (explicit JAX_COORDINATOR_ADDRESS/JAX_NUM_PROCESSES/
JAX_PROCESS_ID, or SLURM's environment under ``srun -n 2``), then trains a small MLP regression with the
project's one training loop (handx_jax.train.train): global batch 8 split over the processes, 12 steps,
a log line per step. Process 0 writes RUN_DIR/metrics.jsonl. Without the variables it is the
single-process reference run, which the test runs in its own process through :func:`run`.
"""

import sys

import jax
import jax.numpy as jnp
import numpy as np

from handx_jax.optim import OptimConfig
from handx_jax.train import TrainConfig, TrainSpec, initialize_distributed, train

rng = np.random.default_rng(0)
X = rng.normal(size=(64, 6)).astype(np.float32)
Y = (np.sin(X @ rng.normal(size=(6, 2))) + 0.1 * rng.normal(size=(64, 2))).astype(np.float32)


def init(key):
    k1, k2 = jax.random.split(key)
    return {"w1": jax.random.normal(k1, (6, 16)) * 0.3, "b1": jnp.zeros(16),
            "w2": jax.random.normal(k2, (16, 2)) * 0.3, "b2": jnp.zeros(2)}


def loss(params, batch, rng, train_mode):
    h = jnp.tanh(batch["x"] @ params["w1"] + params["b1"])
    err = h @ params["w2"] + params["b2"] - batch["y"]
    return jnp.mean(err ** 2), {}


def run(run_dir) -> dict:
    """The training of this test (the single-process reference calls it in its own process)."""
    cfg = TrainConfig(steps=12, batch_size=8, seed=1, log_every=1, ckpt_every=6, wandb="disabled", prefetch=0,
                      optim=OptimConfig(lr=3e-2, warmup_steps=0, grad_clip=0.0))
    return train(run_dir, TrainSpec(init=init, loss=loss, get_batch=lambda idx: {"x": X[idx], "y": Y[idx]},
                                    num_examples=64, cfg=cfg, config={"family": "test", "processes": jax.process_count()}))


if __name__ == "__main__":
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU all-reduce across processes
    initialize_distributed()  # before any other JAX call
    out = run(sys.argv[1])
    print(f"process {jax.process_index()}/{jax.process_count()} devices {jax.device_count()} step {out['step']}",
          flush=True)
