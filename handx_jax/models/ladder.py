"""The diffusion model's named paper-scale sizes, in one place and JAX-free (sweep files read them): the
size ladder of paper Table B and the reference's three configs.

Each size is (layers L, width d, heads H, feed-forward width FF). Table B is the paper's FLOPs ladder at
5% data (App. C; heads d/64 and FF 4·d; the reference's default head count differs, §9.16);
``models.dit`` names its points ``L{L}-d{d}`` in its ``PRESETS``, after the reference's configs
(``paper-4L`` …), and ``sweeps/diffusion_flops_ladder.py`` sweeps them.
"""

TABLE_B = ((2, 256, 4, 1024), (4, 256, 4, 1024), (4, 384, 6, 1536), (8, 384, 6, 1536), (8, 512, 8, 2048),
           (12, 512, 8, 2048), (12, 768, 12, 3072))


# The reference's three configs (reference §3.3; FF 1024), ``models.dit``'s "paper-*" presets.
REFERENCE_SIZES = {"paper-4L": (4, 256, 4, 1024), "paper-8L": (8, 512, 8, 1024), "paper-12L": (12, 512, 8, 1024)}


def table_b_name(L: int, d: int) -> str:
    """The ``models.dit.PRESETS`` name of a Table B point."""
    return f"L{L}-d{d}"


def named_sizes() -> dict[str, tuple[int, int, int, int]]:
    """Every named paper-scale size, in ``models.dit.PRESETS`` order: the reference's configs, then Table B."""
    return {**REFERENCE_SIZES, **{table_b_name(L, d): (L, d, H, F) for L, d, H, F in TABLE_B}}


def size_preset(L: int, d: int, H: int, F: int) -> str | None:
    """The preset that names the size (L, d, H, F) (the first in :func:`named_sizes`, as ``dit.size_name``
    finds it), or None for a size without a name."""
    return next((name for name, size in named_sizes().items() if size == (L, d, H, F)), None)
