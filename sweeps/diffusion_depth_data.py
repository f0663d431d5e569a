"""Diffusion decoder depth × training-data fraction (paper Table 2 / Table 4).

    handx sweep run sweeps/diffusion_depth_data.py --preset paper --data D --encoder E --evaluator V --out OUT

``paper``: layers {4, 8, 12, 16} with Table C's widths × data fraction {0.05, 0.2, 1.0}, 12 runs.
``tiny``: the same 4 × 3 grid shape at CPU sizes (depth {1, 2, 3, 4}, d = 32), minutes per run.

Data fraction: ``sampling="clips"`` (default) takes the nested clip subsets 5% ⊂ 20% ⊂ 100%, each clip
with all its caption levels; ``sampling="pairs"`` samples that fraction of all (clip, caption level)
items as the reference's loader does (reference §1.2), so a clip may appear with only some levels.
"""

from __future__ import annotations

from sweeps.diffusion_common import (FRACTIONS, PAPER_SIZED, RESOURCES, TABLE_C, budget, data,  # noqa: F401 (RESOURCES)
                           diffusion_preset, model)
from sweeps.launcher import RunSpec, axes_of, run_id

TINY_DEPTHS = {1: (32, 64), 2: (32, 64), 3: (32, 64), 4: (32, 64)}


def runs(preset: str = "tiny", steps: int | None = None, sampling: str = "clips",
         fractions: tuple = FRACTIONS) -> list[RunSpec]:
    depths = TABLE_C if preset in PAPER_SIZED else TINY_DEPTHS
    out = []
    for frac in fractions:
        for L, (d, F) in depths.items():
            H = max(d // 64, 4)
            ov = (*model(L, d, H, F), *data(frac, sampling), *budget(preset, steps))
            axes = axes_of(ov, "layers", "dim", "data_fraction")
            out.append(RunSpec(run_id(axes, ov), "diffusion", preset=diffusion_preset(preset, L, d, H, F),
                               overrides=ov, axes=axes))
    return out
