"""XLA compiler options chosen per kind of program (issue 15).

XLA CPU hands dots, and the element-wise and reduction ops around them, to YNNPACK ("__ynn_fusion").
For a training step that is the fastest of the settings tried; for the forward-only inference loops it
is not. In the DDIM + CFG sampler (paper-4L, batch 32) the feed-forward block became one YNN fusion with
both layer norms and the erf GELU inside, fed by three (192, 62, 1024) constant arrays that the fusion
needs materialised (0.5, 1, 1/√2 broadcast), ~100 ms of a ~650 ms step. With YNNPACK off for the
program (Eigen dots, XLA's own fusion emitters for the rest) the same sampler ran 1.146× faster per
step, in-process alternating A/B on the quiet 2-core machine; a training step ran 0.965× (slower), so
only inference programs get it. Narrow models lose instead (DDIM + CFG at batch 256 against XLA's
defaults: width 32 0.82×, 64 0.87×, 128 0.95-0.98×, 192 1.24×, 256 1.15×), so only models at least
``MIN_WIDTH`` wide get it: every Table B size, not the CPU study's or the demo's. Measured figures:
docs/results/perf_cpu.json, ``inference_xla_options_2026_11_24``.

``HANDX_INFERENCE_XLA=default`` in the environment compiles inference programs with XLA's defaults.
"""

from __future__ import annotations

import functools
import os

import jax
import numpy as np

# An empty list of library fusion types: no YNNPACK fusions in the program.
CPU_INFERENCE = {"xla_cpu_experimental_ynn_fusion_type": ""}
MIN_WIDTH = 192  # model width (hidden size) from which the options pay on CPU (measured crossover: 128-192)
ENV = "HANDX_INFERENCE_XLA"


@functools.cache
def _accepted(options: tuple) -> bool:
    """Whether this jaxlib knows the options (an older or newer one may reject an experimental flag)."""
    try:
        jax.jit(lambda x: x + 1, compiler_options=dict(options)).lower(np.float32(0)).compile()
    except Exception:  # noqa: BLE001  (XlaRuntimeError: unknown option or value)
        return False
    return True


def inference_options(width: int) -> dict | None:
    """Compiler options for a forward-only loop (sampling, decoding) of a model ``width`` wide on the
    default backend, or None (XLA's defaults)."""
    if (os.environ.get(ENV, "").strip().lower() == "default" or width < MIN_WIDTH
            or jax.default_backend() != "cpu"):
        return None
    return dict(CPU_INFERENCE) if _accepted(tuple(CPU_INFERENCE.items())) else None


def jit_inference(fn, width: int, **jit_kwargs):
    """``jax.jit`` with :func:`inference_options` for a model ``width`` wide."""
    return jax.jit(fn, compiler_options=inference_options(width), **jit_kwargs)
