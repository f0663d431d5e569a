"""The machine's own matmul peak, measured at benchmark start-up: every throughput figure is
reported beside its fraction of this number (issue 15 §3).

float32 on CPU (the dtype the CPU benchmarks train in), bf16 on a GPU (tensor cores). A jitted
n×n matmul is timed ``repeats`` times after one compiling call; the best repeat gives the peak
(2·n³ FLOPs per call), so background load on a shared machine lowers it the least.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp


def matmul_peak(n: int | None = None, repeats: int = 10, dtype=None) -> dict:
    """{"flops_per_s", "dtype", "n", "device"}: best-of-``repeats`` FLOP/s of a jitted n×n matmul."""
    dev = jax.devices()[0]
    on_gpu = dev.platform == "gpu"
    dtype = dtype or (jnp.bfloat16 if on_gpu else jnp.float32)
    n = n or (8192 if on_gpu else 2048)
    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    a = jax.random.normal(k1, (n, n), dtype)
    b = jax.random.normal(k2, (n, n), dtype)
    inner = 10 if on_gpu else 1  # GPU: several matmuls per timed call so launch overhead vanishes

    @jax.jit
    def mm(a, b):
        out = a @ b
        for _ in range(inner - 1):
            out = a @ out.astype(dtype)
        return out

    jax.block_until_ready(mm(a, b))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(mm(a, b))
        best = min(best, time.perf_counter() - t0)
    return {"flops_per_s": 2.0 * n ** 3 * inner / best, "dtype": jnp.dtype(dtype).name, "n": n,
            "device": dev.device_kind, "seconds_best": best, "repeats": repeats}
