"""The diffusion size ladder of paper Table B, in one place and JAX-free (sweep files read it).

Each point is (layers L, width d, heads H, feed-forward width FF): the paper's FLOPs ladder at 5% data
(App. C; heads d/64 and FF 4·d; the reference's default head count differs, §9.16). ``models.dit``
names them ``L{L}-d{d}`` in its ``PRESETS``; ``sweeps/diffusion_flops_ladder.py`` sweeps them.
"""

TABLE_B = ((2, 256, 4, 1024), (4, 256, 4, 1024), (4, 384, 6, 1536), (8, 384, 6, 1536), (8, 512, 8, 2048),
           (12, 512, 8, 2048), (12, 768, 12, 3072))


def table_b_name(L: int, d: int) -> str:
    """The ``models.dit.PRESETS`` name of a Table B point."""
    return f"L{L}-d{d}"
