"""Diffusion width at fixed depth: d with H = d/64 and FFN = 4d (Table B's proportions).

``paper``: 8 layers, d ∈ {256, 384, 512, 768} (Table B's widths), 5% data. ``tiny``: 2 layers,
d ∈ {16, 32, 64, 128}.
"""

from __future__ import annotations

from sweeps.diffusion_common import PAPER_SIZED, RESOURCES, budget, data, diffusion_preset, model  # noqa: F401 (RESOURCES)
from sweeps.launcher import RunSpec, axes_of, run_id


def runs(preset: str = "tiny", steps: int | None = None, layers: int | None = None, fraction: float = 0.05,
         sampling: str = "clips") -> list[RunSpec]:
    big = preset in PAPER_SIZED
    L = layers or (8 if big else 2)
    widths = (256, 384, 512, 768) if big else (16, 32, 64, 128)
    out = []
    for d in widths:
        H = max(d // 64, 4) if big else 4
        ov = (*model(L, d, H, 4 * d), *data(fraction, sampling), *budget(preset, steps))
        axes = axes_of(ov, "layers", "dim", "data_fraction")
        out.append(RunSpec(run_id(axes, ov), "diffusion", preset=diffusion_preset(preset, L, d, H, 4 * d),
                           overrides=ov, axes=axes))
    return out
