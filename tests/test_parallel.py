import itertools

import pytest

from handx_jax.data.parallel import map_ordered


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

    from handx_jax.data import parallel

    jnp.zeros(1).block_until_ready()
    assert parallel._context().get_start_method() in ("forkserver", "spawn")
    assert list(map_ordered(_square_slowly_first, range(5), 2)) == [0, 1, 4, 9, 16]
