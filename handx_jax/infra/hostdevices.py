"""The host's cores as several CPU devices, for forward-only batches (issue 15).

XLA CPU runs a batched matmul as one small contraction per batch item, one after another on one core:
attention's (sequences × heads) products of 62 × 64 × 62 at paper-4L keep one of the two cores busy
(process CPU time / wall 1.00 for the scores alone, docs/results/perf_cpu.json). Splitting the host into N
CPU devices and a sampling batch into N slices (``shard_map``, no communication: every sample is
independent) runs those products on every core at once, while the large matmuls keep using the shared
intra-op thread pool. DDIM + CFG sampling, one process with 2 devices against one with 1 (2-core machine):
paper-4L at batch 32 1.09-1.14×, L2-d128 at batch 256 1.12×, L2-d64 1.23×. AR decoding (``families.ar.decode``)
splits its batch the same way: greedy KV-cache decoding of the small LM 1.10-1.19× at batch 16, 1.30× at 64.

Training keeps one device per process (``train._mesh``): the loop's data parallelism across two such
devices ran paper-4L at batch 32 at 14.4 samples/s against 26.4 on one (see ``train._mesh``).

The device count must be set before JAX starts its backends, so the entry points call :func:`configure`
first thing (the ``handx`` CLI, the benchmarks); a notebook calls it right after ``import jax``. Without
it every path still works, on one device. ``HANDX_CPU_DEVICES=N`` chooses N (1: one device, as before);
an ``XLA_FLAGS`` that already sets ``--xla_force_host_platform_device_count``, or a ``JAX_NUM_CPU_DEVICES``
set by the user, is left alone.
"""

from __future__ import annotations

import os
import sys

ENV = "HANDX_CPU_DEVICES"
MAX_DEFAULT = 8  # measured on 2 cores only; more slices than this is untested


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def default_count() -> int:
    """``HANDX_CPU_DEVICES`` if set, else the cores this process may run on (at most ``MAX_DEFAULT``)."""
    raw = os.environ.get(ENV, "").strip()
    if raw:
        try:
            n = int(raw)
        except ValueError:
            raise ValueError(f"{ENV}={raw!r}: expected a whole number of CPU devices (1 or more)") from None
        if n < 1:
            raise ValueError(f"{ENV}={raw!r}: expected a whole number of CPU devices (1 or more)")
        return n
    return max(1, min(_cores(), MAX_DEFAULT))


def configure(n: int | None = None) -> int | None:
    """Ask JAX for ``n`` CPU devices (default :func:`default_count`). Returns the count asked for, or None
    where it was left alone: JAX's backends already started, or ``XLA_FLAGS`` names a device count.

    Before ``import jax`` it only sets ``JAX_NUM_CPU_DEVICES`` (JAX reads it at import), so a command
    that never imports JAX does not pay for importing it here."""
    if "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return None
    if n is None and not os.environ.get(ENV, "").strip() and os.environ.get("JAX_NUM_CPU_DEVICES", "").strip():
        return None  # the user asked JAX directly
    n = default_count() if n is None else int(n)
    if "jax" not in sys.modules:
        os.environ["JAX_NUM_CPU_DEVICES"] = str(n)
        return n
    import jax
    from jax._src import xla_bridge

    if xla_bridge.backends_are_initialized():
        return None
    jax.config.update("jax_num_cpu_devices", n)
    return n


def inference_mesh(batch: int):
    """The mesh (axis "b") to split a forward-only batch of ``batch`` samples over, or None for one
    device: only on the CPU backend, with more than one local CPU device, and only where the batch
    divides evenly (an uneven split would need padding, and padding changes the batch's noise draws)."""
    import jax
    import numpy as np
    from jax.sharding import Mesh

    if jax.default_backend() != "cpu":
        return None
    devs = jax.local_devices()
    n = len(devs)
    while n > 1 and batch % n:
        n -= 1
    if n <= 1:
        return None
    return Mesh(np.asarray(devs[:n]), ("b",))


def replicate(mesh, tree):
    """``tree`` on every device of ``mesh``. Arrays committed to one device (restored parameters) cannot
    enter a program that runs on several; this copies them (once per call; a few MB)."""
    import jax
    from jax.sharding import NamedSharding, PartitionSpec

    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec()))
