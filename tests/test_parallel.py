import itertools

import pytest

from handx_jax.dataset.parallel import map_ordered


def _square_slowly_first(x):
    import time

    time.sleep(0.2 if x == 0 else 0.0)  # the first item finishes last; the output must still lead with it
    return x * x


def _fail_on_three(x):
    if x == 3:
        raise ValueError(f"bad item {x}")
    return x


@pytest.mark.parametrize("workers", [1, 3])
def test_map_ordered_keeps_input_order(workers):
    assert list(map_ordered(_square_slowly_first, range(9), workers)) == [x * x for x in range(9)]


def test_map_ordered_endless_input_and_early_close():
    gen = map_ordered(_square_slowly_first, itertools.count(), 2, window=3)
    assert [next(gen) for _ in range(5)] == [0, 1, 4, 9, 16]
    gen.close()  # cancels what has not started, waits for the rest; must not hang


@pytest.mark.parametrize("workers", [1, 2])
def test_map_ordered_raises_the_workers_error(workers):
    with pytest.raises(ValueError, match="bad item 3"):
        list(map_ordered(_fail_on_three, range(6), workers))


def test_map_ordered_avoids_fork_once_jax_runs():
    """After JAX has started its runtime (threads), workers must come from a fresh interpreter: a forked
    child of a threaded process can deadlock. The results are the same either way."""
    import jax.numpy as jnp

    from handx_jax.dataset import parallel

    jnp.zeros(1).block_until_ready()
    assert parallel._context().get_start_method() in ("forkserver", "spawn")
    assert list(map_ordered(_square_slowly_first, range(5), 2)) == [0, 1, 4, 9, 16]


def _children(pid: int) -> list[int]:
    import os

    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat", "rb") as f:
                    fields = f.read().rsplit(b")", 1)[1].split()
                if int(fields[1]) == pid:
                    out.append(int(d))
            except (OSError, IndexError):
                pass
    return out


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except OSError:
        return False


def test_workers_end_with_a_killed_parent():
    """Issue 14.8: `kill -9` of a `data synth` left its pool workers hung forever. They now exit
    within a few seconds of their parent's death."""
    import os
    import signal
    import subprocess
    import sys
    import time

    code = ("import time; from handx_jax.dataset.parallel import map_ordered; "
            "print('go', flush=True); list(map_ordered(time.sleep, [60] * 4, 2))")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "JAX_PLATFORMS": "cpu"})
    try:
        assert parent.stdout.readline().strip() == "go"
        deadline = time.time() + 20
        while len(kids := _children(parent.pid)) < 2 and time.time() < deadline:
            time.sleep(0.1)
        assert len(kids) >= 2, "the pool did not start its workers"
    finally:
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait()
    deadline = time.time() + 5
    while any(map(_running, kids)) and time.time() < deadline:
        time.sleep(0.1)
    alive = [k for k in kids if _running(k)]
    for k in alive:  # do not leave them behind if the test fails
        os.kill(k, signal.SIGKILL)
    assert not alive, f"workers {alive} outlived their parent"
