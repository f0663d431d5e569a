"""G-HTT sizes (depth × width) on the CPU, scored by the prediction benchmark (issue 41 item 5).

Each point is a P run (the shared step ``ghtt-pose`` at that size: the registry says a G-HTT run is trained
from one, so the launcher passes ``--ghtt-pose STEP``) and the A run on it at the same size. The registry
says G-HTT is scored on prediction (``Family.sweep_task``): the generate stage continues the test clips from
their first 16 frames, the standard evaluator scores the completed clips (top-3, FID), and ``handx eval
prediction`` (K = 20 from N(μ, 5Σ)) writes MPJPE-RA/-PA and APD of the predicted frames into the row.

    handx text cache --data D --encoder ENC --joined
    handx sweep run sweeps/ghtt_cpu_study.py --preset cpu --data D --encoder ENC --evaluator standard \\
        --eval-limit 10000 --out S
    handx analyze fit S/results.csv --x flops --y mpjpe_ra_right --plot S/fit.png

``cpu``: depth {1, 2, 3} × width {32, 64, 96}: (1, 32), (2, 32), (2, 64), (3, 96) (CPU_SIZES), the same steps for
every size (CPU_POSE_STEPS, CPU_ACTION_STEPS at batch 64). ``tiny``: two sizes at a few steps (tests).
"""

from __future__ import annotations

from sweeps.diffusion_common import RESOURCES as _RESOURCES
from sweeps.launcher import RunSpec, Step, family_step, run_id

CPU_SIZES = ((1, 32), (2, 32), (2, 64), (3, 96))  # (layers, width) of both blocks
CPU_POSE_STEPS = 800
CPU_ACTION_STEPS = 600
CPU_BATCH = 64
TINY_SIZES = ((1, 16), (1, 32))
RESOURCES = {**_RESOURCES, "cpu": {"timeout_min": 60, "cpus_per_task": 1, "mem_gb": 4}}

TEXT_JOINED = Step("text-joined", (("handx", "text", "cache", "--data", "{data}", "--encoder", "{encoder}",
                                    "--joined"),))


def _size(block: str, L: int, d: int) -> tuple[str, ...]:
    heads = 2 if d < 64 else 4
    return (f"model.{block}.layers={L}", f"model.{block}.dim={d}", f"model.{block}.heads={heads}",
            f"model.{block}.ff={4 * d}")


def runs(preset: str = "cpu", pose_steps: int | None = None, action_steps: int | None = None,
         sizes: tuple | None = None, pose_set: tuple = (), action_set: tuple = ()) -> list[RunSpec]:
    """``pose_set``/``action_set``: more dotted overrides of every P step / every A run."""
    if preset not in ("cpu", "tiny"):
        raise ValueError(f"unknown preset {preset!r} (cpu | tiny)")
    grid = [tuple(s) for s in sizes] if sizes else list(CPU_SIZES if preset == "cpu" else TINY_SIZES)
    ps = pose_steps or (CPU_POSE_STEPS if preset == "cpu" else 4)
    st = action_steps or (CPU_ACTION_STEPS if preset == "cpu" else 4)
    loop = lambda n: (f"train.steps={n}", f"train.batch_size={CPU_BATCH}", f"train.log_every={max(n // 10, 1)}",  # noqa: E731
                      f"train.ckpt_every={n}", f"train.eval_every={n}", "train.wandb=disabled")
    out = []
    for L, d in reversed(grid):  # largest first: two at a time finish together
        pose = family_step("ghtt-pose", f"ghtt-pose-L{L}-d{d}", "tiny", (*_size("pose", L, d), *loop(ps), *pose_set))
        ov = (*_size("action", L, d), *loop(st), *action_set)
        axes = {"layers": L, "dim": d}
        out.append(RunSpec(run_id(axes, ("tiny", pose.key, *ov)), "ghtt", preset="tiny", overrides=ov, axes=axes,
                           needs=(TEXT_JOINED, pose)))
    return out
