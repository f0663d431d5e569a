"""The machine's own matmul peak, measured at benchmark start-up: every throughput figure is
reported beside its fraction of this number (issue 15 §3).

float32 on CPU (the dtype the CPU benchmarks train in), bf16 on a GPU (tensor cores). A jitted
n×n matmul is timed ``repeats`` times after one compiling call; the best repeat gives the peak
(2·n³ FLOPs per call), so background load on a shared machine lowers it the least.
"""

from __future__ import annotations

import json
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


# Peak dense bf16 tensor-core FLOP/s (vendor datasheets, without sparsity), for MFU on a GPU.
PEAK_BF16 = {
    "H200": 989.4e12,  # H200 SXM
    "H100 PCIe": 756.0e12,
    "H100": 989.4e12,  # H100 SXM (HBM3)
    "A100": 312.0e12,
    "L4": 121.0e12,
}


def device_peak(kind: str) -> float | None:
    """The datasheet bf16 peak of a GPU by its ``device_kind`` (None when unknown)."""
    for name, peak in PEAK_BF16.items():  # most specific first
        if name in kind:
            return peak
    return None


def emit(doc: dict, out: str | None = None, indent: int = 2) -> None:
    """Every benchmark's ending: the JSON document on stdout and, with ``--out``, written atomically.

    It records the host memory policy the figures were taken under (``handx_jax.infra.hostmem``: on CPU
    it moved paper-4L training from 16.7 to 26.4 samples/s in one A/B, docs/results/perf_cpu.json)."""
    from handx_jax.infra import hostmem

    doc = {**doc, "host_malloc": dict(hostmem.STATE)}
    text = json.dumps(doc, indent=indent)
    print(text)
    if out:
        from handx_jax.infra.atomic import atomic_write_text

        atomic_write_text(out, text + "\n")
