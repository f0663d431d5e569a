"""Diffusion FLOPs ladder at 5% data (paper Table B / Fig. 4).

``paper``: Table B's seven (L, d, H, FFN) sizes, 3.83 → 24.62 GFLOPs in the paper's convention
(``handx params diffusion --convention paper``), for the paper's ~100k steps. ``short``: the same seven
sizes for 1,000 steps × 128 at lr 5e-4 (``sweeps.diffusion_common.budget``): the ladder one short GPU lease trains
(docs/results/fig4_gpu). ``tiny``: a seven-step CPU ladder with the same
shape (depth and width grow in turn), for checking train → evaluate → fit end to end.
"""

from __future__ import annotations

from sweeps.diffusion_common import (PAPER_SIZED, RESOURCES, TABLE_B, budget, data,  # noqa: F401 (RESOURCES)
                           diffusion_preset, model)
from sweeps.launcher import RunSpec, axes_of, run_id

# Table B and Fig. 4 report R-Precision at block 16 (Tables 2-5: 32); the paper's slope 0.4391 is in those units.
RPREC_BLOCK = 16

TINY_LADDER = ((1, 32, 4, 64), (2, 32, 4, 64), (2, 48, 4, 96), (3, 48, 4, 96), (3, 64, 4, 128), (4, 64, 4, 128),
               (4, 96, 4, 192))


def runs(preset: str = "tiny", steps: int | None = None, fraction: float = 0.05,
         sampling: str = "clips", lr: float | None = None, sizes: tuple | None = None) -> list[RunSpec]:
    """``lr`` replaces the preset's learning rate (one for every size); ``sizes`` keeps only the ladder's
    sizes given as (layers, dim) pairs, e.g. ``sizes=[(12, 768)]``."""
    ladder = TABLE_B if preset in PAPER_SIZED else TINY_LADDER
    if sizes is not None:
        keep = {tuple(int(v) for v in s) for s in sizes}
        missing = keep - {(L, d) for L, d, _, _ in ladder}
        if missing:
            raise ValueError(f"sizes {sorted(missing)} are not on the {preset} ladder "
                             f"{[(L, d) for L, d, _, _ in ladder]}")
        ladder = tuple(x for x in ladder if (x[0], x[1]) in keep)
    out = []
    for L, d, H, F in ladder:
        ov = (*model(L, d, H, F), *data(fraction, sampling), *budget(preset, steps),
              *(() if lr is None else (f"train.optim.lr={float(lr):g}",)))
        axes = axes_of(ov, "layers", "dim", "heads", "ff", "data_fraction")
        out.append(RunSpec(run_id(axes, ov), "diffusion", preset=diffusion_preset(preset, L, d, H, F),
                           overrides=ov, axes=axes))
    return out
