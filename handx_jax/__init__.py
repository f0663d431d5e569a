"""handx-jax: text-to-bimanual-hand-motion generation in JAX, built for scaling-law sweeps.

Importing the package sets the host memory policy (:mod:`handx_jax.infra.hostmem`) before JAX starts its
CPU threads, so XLA's per-step buffers are reused instead of page-faulted in anew every step.
"""

import warnings as _warnings

from handx_jax.infra import hostmem as _hostmem

try:
    _hostmem.configure()
except ValueError as _e:  # a bad $HANDX_HOST_MALLOC: say so, keep glibc's defaults
    _warnings.warn(f"{_e}; keeping glibc's malloc defaults", stacklevel=2)
    _hostmem.configure("system")
