"""The host memory policy (handx_jax.infra.hostmem): XLA's large per-call buffers are reused, not page-faulted in."""

import importlib
import json
import os
import subprocess
import sys
import textwrap
import warnings

import pytest

import handx_jax
from handx_jax.infra import hostmem

# A jitted function whose (4096 × 4096) float32 intermediate, 64 MiB = 16,384 pages of 4 KiB, lies above
# glibc's 32 MiB mmap ceiling: with glibc's defaults every call maps it afresh and the kernel zero-fills
# each page on first touch; with the reuse policy the pages of the previous call are handed back.
PROBE = textwrap.dedent("""
    import json, resource
    import handx_jax
    from handx_jax.infra import hostmem
    import jax, jax.numpy as jnp
    x = jnp.ones((4096, 256)); w = jnp.full((256, 4096), 1e-3)
    f = jax.jit(lambda x, w: jnp.sum(jnp.tanh(x @ w) @ w.T))
    for _ in range(2):
        f(x, w).block_until_ready()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(5):
        f(x, w).block_until_ready()
    faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 5
    print(json.dumps({"faults_per_call": faults, **hostmem.STATE}))
""")

glibc_linux = pytest.mark.skipif(not hostmem.supported(), reason="the policy applies to glibc's malloc on Linux only")


def _probe(policy: str) -> dict:
    env = {**os.environ, "HANDX_HOST_MALLOC": policy, "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@glibc_linux
def test_reuse_policy_stops_the_page_faults_of_large_buffers():
    system, reuse = _probe("system"), _probe("reuse")
    assert (system["policy"], system["applied"]) == ("system", False)
    assert (reuse["policy"], reuse["applied"]) == ("reuse", True)
    # What the project promises on any machine: the policy never makes a call fault in more pages than
    # glibc's defaults (a few hundred pages of slack for the interpreter's own allocations).
    assert reuse["faults_per_call"] <= system["faults_per_call"] + 256, (reuse, system)
    # The problem the policy solves shows only where glibc maps the 64 MiB intermediate afresh on every
    # call (at least half its 16,384 pages fault in). Some kernels/glibc builds keep the mapping warm
    # (1,031 faults per call measured on one of this project's machines): nothing to fix there.
    if system["faults_per_call"] <= 8000:
        pytest.skip(f"glibc's defaults fault in only {system['faults_per_call']:.0f} pages per call here "
                    f"(reuse policy: {reuse['faults_per_call']:.0f}); the 64 MiB buffer is not re-faulted "
                    "on this machine, so there is nothing for the policy to stop")
    # the reuse policy: the same memory comes back, so (almost) nothing faults
    assert reuse["faults_per_call"] < 0.05 * system["faults_per_call"], (reuse, system)


def test_policy_names_are_checked_and_a_bad_one_keeps_glibc_defaults(monkeypatch):
    with pytest.raises(ValueError, match="HANDX_HOST_MALLOC='fast'"):
        hostmem.configure("fast")
    monkeypatch.setenv("HANDX_HOST_MALLOC", "fast")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        importlib.reload(handx_jax)  # the package applies the policy at import and must not fail there
    assert any("keeping glibc's malloc defaults" in str(w.message) for w in caught)


@glibc_linux
def test_the_test_process_runs_under_the_reuse_policy():
    # conftest leaves HANDX_HOST_MALLOC unset, so the package default applies to the whole suite
    if os.environ.get("HANDX_HOST_MALLOC", "reuse") != "reuse":
        pytest.skip("HANDX_HOST_MALLOC is set for this run")
    assert hostmem.STATE["policy"] == "reuse" and hostmem.STATE["applied"] is True


# Two steps in flight keep two of those buffers alive, ~2 GB for paper-4L; when both are freed the heap's
# top holds more than any positive trim threshold mallopt accepts (at most 2^31 - 1), so glibc gave the
# pages back and the next steps faulted them in again (docs/results/perf_cpu.json, trim_2026_11_24).
# The probe frees a 2.5 GiB heap block (never touched: no page is faulted in) and reads the heap's end.
TRIM_PROBE = textwrap.dedent("""
    import ctypes, json
    import handx_jax
    libc = ctypes.CDLL("libc.so.6")
    libc.sbrk.restype = ctypes.c_void_p; libc.sbrk.argtypes = [ctypes.c_ssize_t]
    libc.malloc.restype = ctypes.c_void_p; libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    start = libc.sbrk(0)
    p = libc.malloc(5 << 29)
    grown = libc.sbrk(0)
    libc.free(p)
    print(json.dumps({"malloc_ok": bool(p), "grown": grown - start, "after_free": libc.sbrk(0) - start}))
""")


@glibc_linux
def test_reuse_policy_keeps_a_freed_heap_top_larger_than_2_gib():
    env = {**os.environ, "HANDX_HOST_MALLOC": "reuse", "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", TRIM_PROBE], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["malloc_ok"] and r["grown"] >= 5 << 29, r  # served from the heap (no mmap), not vacuous
    assert r["after_free"] == r["grown"], r  # nothing trimmed
