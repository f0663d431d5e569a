"""Diffusion scaling sweeps (paper Table B / Fig. 4), written as plain Python.

``runs(grid=...)`` returns the list of runs; the launcher (``handx sweep run``) does the rest.

- ``paper``: Table B's seven (L, d, H, FFN) points on the 5% data fraction (paper App. C).
- ``cpu``: a small depth × width × data-fraction grid that trains in minutes per run on a CPU,
  for checking the whole pipeline (train → generate → evaluate → fit) end to end.
"""

from __future__ import annotations

from sweeps.launcher import RunSpec

# Table B (L, d, H, FFN); the reference code's default head count differs (§9.16).
TABLE_B = ((2, 256, 4, 1024), (4, 256, 4, 1024), (4, 384, 6, 1536), (8, 384, 6, 1536), (8, 512, 8, 2048),
           (12, 512, 8, 2048), (12, 768, 12, 3072))


def _model(L: int, d: int, H: int, F: int) -> tuple[str, ...]:
    return (f"model.layers={L}", f"model.dim={d}", f"model.heads={H}", f"model.ff={F}")


def runs(grid: str = "cpu", steps: int | None = None, fraction: float | None = None) -> list[RunSpec]:
    if grid == "paper":
        frac = 0.05 if fraction is None else fraction
        st = steps or 100_000
        return [RunSpec(name=f"L{L}-d{d}", preset="paper-4L",
                        overrides=(*_model(L, d, H, F), f"data.fraction={frac}", f"train.steps={st}"))
                for L, d, H, F in TABLE_B]
    if grid == "cpu":
        st = steps or 300
        out = []
        for L, d in ((1, 32), (2, 64), (2, 128), (4, 128)):
            for frac in ((1.0,) if fraction is None else (fraction,)):
                out.append(RunSpec(name=f"L{L}-d{d}-f{frac:g}", preset="tiny",
                                   overrides=(*_model(L, d, 4, 2 * d), f"data.fraction={frac}", f"train.steps={st}",
                                              "train.batch_size=32", "train.log_every=25",
                                              f"train.ckpt_every={max(st // 2, 1)}")))
        return out
    raise ValueError(f"unknown grid {grid!r} (cpu | paper)")
