"""Order-preserving process-pool map with a bounded window.

The corpus build (synthesis chunks) and the dataset statistics (feature moments, contact and intensity
per clip chunk) are embarrassingly parallel but must give the numbers of a serial run: results come
back in input order, so every later reduction sums them in the same order whatever ``workers`` is.
"""

from __future__ import annotations

import collections
import multiprocessing as mp
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def map_ordered(fn: Callable[[T], R], items: Iterable[T], workers: int, *, window: int | None = None) -> Iterator[R]:
    """Yield ``fn(item)`` for each item, in order, computed by ``workers`` processes (≤ 1: inline).

    At most ``window`` (default 2·workers) items are in flight, so ``items`` may be endless and the
    results held at once stay bounded; closing the generator early cancels what has not started.
    ``fn`` and the items must be picklable (module-level functions, ``functools.partial`` of them).
    """
    if workers <= 1:
        for item in items:
            yield fn(item)
        return
    window = window or 2 * workers
    source = iter(items)
    with ProcessPoolExecutor(max_workers=workers, mp_context=_context()) as ex:
        pending: collections.deque = collections.deque()
        try:
            while True:
                while len(pending) < window:
                    item = next(source, _END)
                    if item is _END:
                        break
                    pending.append(ex.submit(fn, item))
                if not pending:
                    return
                yield pending.popleft().result()
        finally:
            for f in pending:
                f.cancel()


_END = object()


def _context():
    """fork (cheap: workers inherit the loaded modules) unless this process has started the JAX runtime,
    whose threads can leave a forked child deadlocked (JAX warns so); then a fresh-interpreter start."""
    methods = mp.get_all_start_methods()
    if "fork" in methods and not _jax_runtime_started():
        return mp.get_context("fork")
    return mp.get_context("forkserver" if "forkserver" in methods else "spawn")


def _jax_runtime_started() -> bool:
    if "jax" not in sys.modules:  # never imported: nothing to ask, and no reason to import it here
        return False
    try:
        from jax._src import xla_bridge
        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # another JAX layout: assume the worst
        return True
