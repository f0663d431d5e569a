"""Order-preserving process-pool map with a bounded window.

The corpus build (synthesis chunks) and the dataset statistics (feature moments, contact and intensity
per clip chunk) are embarrassingly parallel but must give the numbers of a serial run: results come
back in input order, so every later reduction sums them in the same order whatever ``workers`` is.
"""

from __future__ import annotations

import collections
import multiprocessing as mp
import os
import sys
import threading
import time
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
    with ProcessPoolExecutor(max_workers=workers, mp_context=_context(), initializer=end_with_parent,
                             initargs=(os.getpid(),)) as ex:
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
        except BaseException:  # a worker's error, or the caller closed the generator early
            for f in pending:
                f.cancel()
            # End the pool without waiting on it: Python 3.11.2's ProcessPoolExecutor (Debian's python3) hangs
            # in shutdown(wait=True) after a worker's error under forkserver in 3 of 4 runs of
            # tests/test_parallel.py's error test (and in 4 of 8 after an early close under fork); 3.11.7 does not.
            # Nothing the caller still wants is running: the results not yet yielded are abandoned either way.
            ex.shutdown(wait=False, cancel_futures=True)
            for proc in list((getattr(ex, "_processes", None) or {}).values()):
                proc.terminate()
            raise


_END = object()


def end_with_parent(parent_pid: int, poll_s: float = 0.5) -> None:
    """Worker initializer: exit when the process that owns the pool dies, even by ``kill -9`` (which
    runs no clean-up, so the pool cannot stop its workers; they would hang on forever, issue 14.8).

    A daemon thread polls the owner's pid. Not ``prctl(PR_SET_PDEATHSIG)``: it fires when the *thread*
    that forked the worker exits, and under forkserver the worker's parent is the server, not the owner.
    """
    def watch() -> None:
        while _alive(parent_pid):
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else (pid reused): not our owner any more
        return False
    try:  # a killed owner not yet reaped by its own parent is a zombie: dead for our purpose
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except (OSError, IndexError):
        return True


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
