"""A cache for what a model config alone determines (parameter counts, jitted programs).

Programs: a jitted function built for one config serves every model of that config in a process.

Counting parameters traces the model's init under ``jax.eval_shape``: ~0.5-0.8 CPU-s at the paper's sizes
on CPU, paid by every run's record, every sweep row and every ``handx params``. The answer depends only on
the (frozen) config, so it is computed once per config and process. A config holding something unhashable
(e.g. a list read back from JSON) is simply computed again each time.
"""

from __future__ import annotations

import functools


def per_config(fn):
    """``fn(cfg)`` cached per hashable ``cfg`` (up to 128 configs per process)."""
    cached = functools.lru_cache(maxsize=128)(fn)

    @functools.wraps(fn)
    def wrapper(cfg):
        try:
            hash(cfg)
        except TypeError:
            return fn(cfg)
        return cached(cfg)

    wrapper.cache_clear = cached.cache_clear
    return wrapper
