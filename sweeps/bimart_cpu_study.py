"""BimArt sizes (depth × width of the motion model) on the CPU, scored by BimArt's metrics (issue 53 item 6).

Each point is a contact generator (the shared step ``bimart-contact``: the registry says a BimArt run is trained
from one, so the launcher passes ``--bimart-contact STEP``; one step serves every motion size) and the motion run
on it. The registry says BimArt is scored on ``object2motion`` (``Family.sweep_task``): the generate stage writes
hands for the test split's objects and trajectories (``handx generate --task object2motion``), and ``handx eval
objects`` puts Pen 1cm / 5mm, Con, Art, part F1, CM, Mul and Accel into the row. No text evaluator is read.

    handx data objects --clips 2000 --out D
    handx sweep run sweeps/bimart_cpu_study.py --preset cpu --data D --eval-limit 32 --eval-samples 2 --out S
    handx analyze fit S/results.csv --x compute --y obj_pen_1cm --plot S/fit.png

``cpu``: depth {1, 2, 4} × width {32, 64, 128} at four sizes (CPU_SIZES), the same steps for every size. ``tiny``:
one size at a few steps (tests, smoke). The committed sweep (docs/results/bimart/size_sweep/v3/) ran the cpu preset
with ``--arg steps=2000 --arg 'sizes=[[1,32],[2,64],[3,96]]' --eval-limit 16 --eval-samples 2`` on a 2,000-clip
corpus (its first version, size_sweep/: 600 steps, ``--set sample.refine=false``, 200 clips).
"""

from __future__ import annotations

from sweeps.diffusion_common import RESOURCES as _RESOURCES
from sweeps.launcher import RunSpec, family_step, run_id

CPU_SIZES = ((1, 32), (2, 64), (4, 64), (4, 128))  # (layers, width) of the motion model
CPU_CONTACT_SIZE = (2, 64)
CPU_STEPS = 1500
CPU_BATCH = 32
TINY_SIZES = ((1, 16),)
RESOURCES = {**_RESOURCES, "cpu": {"timeout_min": 60, "cpus_per_task": 1, "mem_gb": 4}}


def _size(L: int, d: int) -> tuple[str, ...]:
    return (f"model.block.layers={L}", f"model.block.dim={d}", f"model.block.heads={2 if d < 64 else 4}",
            f"model.block.ff={4 * d}")


def runs(preset: str = "cpu", steps: int | None = None, sizes: tuple | None = None, motion_set: tuple = (),
         contact_set: tuple = ()) -> list[RunSpec]:
    """``motion_set``/``contact_set``: more dotted overrides of every motion run / the contact step."""
    if preset not in ("cpu", "tiny"):
        raise ValueError(f"unknown preset {preset!r} (cpu | tiny)")
    grid = [tuple(s) for s in sizes] if sizes else list(CPU_SIZES if preset == "cpu" else TINY_SIZES)
    n = steps or (CPU_STEPS if preset == "cpu" else 2)
    loop = (f"train.steps={n}", f"train.batch_size={CPU_BATCH}", f"train.log_every={max(n // 10, 1)}",
            f"train.ckpt_every={n}", "train.wandb=disabled")
    cL, cd = CPU_CONTACT_SIZE if preset == "cpu" else grid[0]
    contact = family_step("bimart-contact", f"bimart-contact-L{cL}-d{cd}", "tiny", (*_size(cL, cd), *loop, *contact_set))
    out = []
    for L, d in reversed(grid):  # largest first
        # tiny: a two-iteration refinement (the sweep's generate stage reads the run's own sample.* overrides)
        short = () if preset == "cpu" else ("sample.refine_cfg.fit_iters=2", "sample.refine_cfg.iters=2")
        ov = (*_size(L, d), *loop, *short, *motion_set)
        axes = {"layers": L, "dim": d}
        out.append(RunSpec(run_id(axes, ("tiny", contact.key, *ov)), "bimart", preset="tiny", overrides=ov, axes=axes,
                           needs=(contact,)))
    return out
