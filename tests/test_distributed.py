"""Multi-process data-parallel training for real (issue 13.6): two CPU processes with jax.distributed.

Two processes on localhost (a coordinator port, gloo CPU collectives) train the same small model as one
process (the test's own) does, through the project's training loop (handx_jax.train.train): each loads half
of every global batch, gradients are averaged across processes, process 0 writes the run files. The loss curve
must match the single-process run to 1e-5 relative at every step: the same data order and the same
maths, only the batch mean is reduced across two devices instead of one (float32 summation order).
"""

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
WORKER = str(HERE / "distributed_worker.py")
TOL = 1e-5


def _env(**kw):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COORDINATOR", "JAX_NUM_PROC", "JAX_PROCESS",
                                                                     "SLURM_"))}
    return {**env, "PYTHONPATH": str(HERE.parent), "JAX_PLATFORMS": "cpu", "WANDB_MODE": "disabled",
            "XLA_FLAGS": "--xla_force_host_platform_device_count=1", **kw}


def _losses(run: Path) -> list[float]:
    rows = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == list(range(1, 13))
    return [r["loss"] for r in rows]


def test_two_processes_match_one(tmp_path):
    t0 = time.time()
    # The single-process reference in this process (its worker file's own function): a third Python process
    # would cost its imports and compiles again (~4 CPU-s) for the same numbers.
    from tests.distributed_worker import run

    assert run(tmp_path / "one")["step"] == 12
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    procs = [subprocess.Popen([sys.executable, WORKER, str(tmp_path / "two")], stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True,
                              env=_env(JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{port}", JAX_NUM_PROCESSES="2",
                                       JAX_PROCESS_ID=str(i)))
             for i in range(2)]
    logs = []
    for p in procs:
        try:
            logs.append(p.communicate(timeout=120)[0])
        finally:
            if p.poll() is None:
                p.kill()
    assert all(p.returncode == 0 for p in procs), "\n".join(x[-2000:] for x in logs)
    assert "process 0/2 devices 2 step 12" in logs[0] and "process 1/2 devices 2 step 12" in logs[1]
    one, two = _losses(tmp_path / "one"), _losses(tmp_path / "two")
    assert one[-1] < 0.8 * one[0]  # it trains
    for a, b in zip(one, two):
        assert abs(a - b) <= TOL * abs(a), (one, two)
    print(f"2-process test: {time.time() - t0:.1f} s; max rel diff "
          f"{max(abs(a - b) / abs(a) for a, b in zip(one, two)):.2e}")
