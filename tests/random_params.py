"""Parameters of a model's structure drawn on the host, for tests whose assertion holds for any weights.

A flax ``init`` costs an XLA compilation of every initialiser's random draws: 3-6 s of CPU for the tiny T5,
denoiser and LM presets at the suite's optimisation level, more than the rest of such a test. Where what is
checked is a property of the computation (padding invariance, causality, a batch split that does not change
the numbers, a cache that reads back what the encoder gives), ``jax.eval_shape`` of the init (tracing only)
and a seeded host draw give a parameter tree of the same structure, shapes and dtypes at no compile cost.
"""

from __future__ import annotations


def random_params(init, seed: int, scale: float = 0.1):
    """``init(rng)``'s tree of arrays, every leaf N(0, scale²) from numpy's generator ``seed`` (deterministic)."""
    import jax
    import numpy as np

    rng = np.random.default_rng(seed)
    shapes = jax.eval_shape(init, jax.random.PRNGKey(0))
    return jax.tree_util.tree_map(lambda s: (scale * rng.standard_normal(s.shape)).astype(s.dtype), shapes)
