"""handx_jax.models.shape_cache.per_config: parameter counts traced once per config and process."""

from dataclasses import dataclass, field


def test_per_config_caches_hashable_configs_and_recomputes_the_rest():
    from handx_jax.models.shape_cache import per_config

    calls = []

    @per_config
    def count(cfg):
        calls.append(cfg)
        return sum(cfg.sizes) if isinstance(cfg.sizes, (list, tuple)) else cfg.sizes

    @dataclass(frozen=True)
    class Frozen:
        sizes: tuple = (1, 2)

    @dataclass(frozen=True)
    class FromJson:  # a list read back from config.json: not hashable
        sizes: list = field(default_factory=lambda: [3, 4])

    assert count(Frozen()) == 3 and count(Frozen()) == 3 and len(calls) == 1
    assert count(Frozen((5,))) == 5 and len(calls) == 2  # another config, another answer
    assert count(FromJson()) == 7 and count(FromJson()) == 7 and len(calls) == 4


def test_cached_counts_equal_a_fresh_trace():
    import jax
    import numpy as np

    from handx_jax.families.diffusion import make_config
    from handx_jax.models import dit

    cfg = make_config("tiny").model
    fresh = jax.eval_shape(lambda r: dit.init_denoiser(cfg, r)[1], jax.random.PRNGKey(0))
    want = sum(int(np.prod(s.shape)) for s in jax.tree_util.tree_leaves(fresh))
    assert dit.param_count(cfg) == want == dit.param_count(cfg)
