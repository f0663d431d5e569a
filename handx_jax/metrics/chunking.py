"""The chunked map the per-clip, per-frame scans share (Procrustes, penetration, contact distances):
``lax.map`` over ``MOTION_CHUNK`` clips at a time, so their temporaries stay in cache."""

from __future__ import annotations

import jax
import jax.numpy as jnp


MOTION_CHUNK = 50  # clips per lax.map step of the per-frame Procrustes, penetration and contact scans


def map_chunks(fn, *xs_N):
    """``fn`` over chunks of MOTION_CHUNK clips of equally long leading axes (lax.map: the per-frame
    temporaries of 6,000 clips would not fit in cache); zero-padded rows are computed and dropped."""
    n = xs_N[0].shape[0]
    c = max(1, min(MOTION_CHUNK, n))
    k = -(-n // c)
    pad = lambda x: jnp.pad(x, [(0, k * c - n)] + [(0, 0)] * (x.ndim - 1)).reshape(k, c, *x.shape[1:])
    out = jax.lax.map(lambda a: fn(*a), tuple(pad(x) for x in xs_N))
    return jax.tree_util.tree_map(lambda o: o.reshape(k * c, *o.shape[2:])[:n], out)
