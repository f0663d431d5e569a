"""What software produced a run: recorded in every run folder's ``config.json`` (``handx_jax.train``)
and every sweep run's ``provenance.json`` (``sweeps/launcher.py``), beside the git commit.

The same seed and config give the same numbers only with the same numerical stack: jax/jaxlib (XLA's
fusions and reductions), flax and optax (initialisers, optimizer updates), orbax (what a checkpoint
restores), numpy (data pipeline, metrics). ``constraints.txt`` pins them for installs (``make lock``);
this records what a given run actually had. Read with ``importlib.metadata``, so nothing is imported
(the sweep launcher does not start JAX).
"""

from __future__ import annotations

import platform
from importlib import metadata

PACKAGES = ("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "numpy")


def versions() -> dict[str, str | None]:
    """{"python": …, "jax": …, "jaxlib": …, "flax": …, "optax": …, "orbax-checkpoint": …, "numpy": …};
    None for a package that is not installed."""

    def version(name: str) -> str | None:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    return {"python": platform.python_version(), **{name: version(name) for name in PACKAGES}}
