"""Host memory policy for XLA on CPU: reuse freed buffers instead of returning them to the kernel.

Why (issue 15, measured in ``docs/results/perf_cpu.json``, ``host_malloc``). XLA's CPU runtime
mallocs each execution's temporary buffer from a worker thread; for a paper-4L training step at
batch 32 that buffer is ~1 GB. glibc serves a request that size from a thread's arena by a fresh
``mmap`` and frees it with ``munmap``. Every step therefore touches ~250k new 4 KiB pages, and the
kernel zero-fills each one on its first write (``perf record -e page-faults``: 3.2M faults in 11
steps, inside the dot kernels and fused loops). On the 2-core CPU the jitted step took 1.42 s with
glibc's defaults and 1.15 s with this policy; a DDIM + CFG step 0.82 s and 0.68 s. The same holds
for any single array above glibc's 32 MiB mmap ceiling: a jitted (11904, 256) × (256, 1024) matmul,
the feed-forward's first layer in sampling, ran at 105 GFLOP/s, and at 185 with this policy.

The fix is three ``mallopt`` settings, made before XLA starts its threads:

* ``M_ARENA_MAX = 1``: worker threads allocate from the main arena. A thread arena cannot hold a
  request larger than its 64 MiB heap and falls back to ``mmap`` whatever the other settings say.
* ``M_MMAP_MAX = 0``: large requests come from the heap (``brk``), not from ``mmap``.
* ``M_TRIM_THRESHOLD = -1``: freed memory at the heap's top is never given back (mallopt(3): -1
  disables trimming). A finite threshold is not enough: mallopt takes an int, so ~2 GiB is the
  largest, and the training loop keeps two steps in flight, whose two ~1 GB buffers free more than
  that at once. With the 2 GiB threshold a 30-step paper-4L run faulted in 3.4M pages (24.6 s of
  sys time) and trained at 17.9 samples/s; with none, 1.2M pages once and 22.0-23.6 samples/s.

The cost is the one a GPU caching allocator has: the process keeps its peak host memory until it
exits. ``HANDX_HOST_MALLOC=system`` keeps glibc's defaults (set it before Python starts, or before
the first ``import handx_jax``). Only glibc on Linux is touched; elsewhere :func:`configure` does
nothing and says so. Calling it after JAX has run a computation is harmless but gains less: the
worker threads already own their arenas.
"""

from __future__ import annotations

import ctypes
import os
import platform

ENV = "HANDX_HOST_MALLOC"
# mallopt(3) parameter numbers (glibc malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_MAX, _M_ARENA_MAX = -1, -4, -8
TRIM_THRESHOLD = -1  # never trim (an int parameter: -1 is SIZE_MAX to glibc)

# What configure() did, recorded by every benchmark's JSON: {"policy", "applied", "reason"}.
STATE: dict = {"policy": "system", "applied": False, "reason": "not configured"}


def supported() -> bool:
    """The policy applies to glibc's malloc on Linux only."""
    return platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"


def configure(policy: str | None = None) -> dict:
    """Apply ``policy`` ("reuse", the default, or "system"; ``$HANDX_HOST_MALLOC`` when None) once
    per process and return :data:`STATE`."""
    policy = (policy or os.environ.get(ENV) or "reuse").strip().lower()
    if policy not in ("reuse", "system"):
        raise ValueError(f"{ENV}={policy!r}: expected 'reuse' or 'system'")
    if STATE.get("policy") == "reuse" and STATE.get("applied"):
        return STATE  # glibc has no way back to its dynamic defaults; keep what was applied
    if policy == "system":
        STATE.update(policy="system", applied=False, reason=f"{ENV}=system: glibc defaults")
        return STATE
    if not supported():
        STATE.update(policy="system", applied=False, reason=f"not glibc on Linux ({platform.system()})")
        return STATE
    try:
        libc = ctypes.CDLL("libc.so.6")
        ok = all(libc.mallopt(p, v) == 1 for p, v in ((_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0),
                                                        (_M_TRIM_THRESHOLD, TRIM_THRESHOLD)))
    except (OSError, AttributeError) as e:
        STATE.update(policy="system", applied=False, reason=f"mallopt unavailable ({e})")
        return STATE
    STATE.update(policy="reuse", applied=ok, reason="arena_max=1, mmap_max=0, no trim" if ok
                 else "mallopt refused a setting")
    return STATE
