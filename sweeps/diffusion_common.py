"""Pieces shared by the sweep files: dotted overrides for a model size and a training budget."""

from __future__ import annotations

from handx_jax.models.ladder import TABLE_B, size_preset  # noqa: F401 (TABLE_B: (L, d, H, FFN), for the sweep files)

# Table C's diffusion sizes by depth (L -> d, FFN); heads are not printed: d / 64 as in Table B.
TABLE_C = {4: (256, 1024), 8: (512, 1024), 12: (512, 1024), 16: (768, 3072)}
FRACTIONS = (0.05, 0.2, 1.0)  # the nested clip subsets of Table 2 (5% ⊂ 20% ⊂ 100%)

# SLURM resources per preset (submitit parameters). Every preset names its time limit: submitit's
# default of 5 minutes would otherwise end paper-size runs silently.
RESOURCES = {
    "tiny": {"timeout_min": 60, "cpus_per_task": 2, "mem_gb": 8},
    "short": {"timeout_min": 2 * 60, "gpus_per_node": 1, "cpus_per_task": 8, "mem_gb": 64},
    "paper": {"timeout_min": 48 * 60, "gpus_per_node": 1, "cpus_per_task": 8, "mem_gb": 64},
}
# Presets that train the paper's model sizes (``tiny`` trains CPU sizes).
PAPER_SIZED = ("paper", "short")


def model(L: int, d: int, H: int, F: int) -> tuple[str, ...]:
    return (f"model.layers={L}", f"model.dim={d}", f"model.heads={H}", f"model.ff={F}")


def diffusion_preset(preset: str, L: int, d: int, H: int, F: int) -> str:
    """The diffusion ``--preset`` of a sweep point of size (L, d, H, F), which ``model()`` also sets: ``tiny``
    under the CPU sweep presets; for the paper-sized ones the name ``models/ladder.py`` gives the size (a
    Table B point or one of the reference's configs), and for a size it does not name the reference's
    smallest config, ``paper-4L``, as the base the overrides resize. A run records the size it has either
    way (``dit.size_name``: the same name for a named size, ``L{L}-d{d}-H{H}-F{F}`` for another)."""
    if preset not in PAPER_SIZED:
        return "tiny"
    return size_preset(L, d, H, F) or "paper-4L"


def budget(preset: str, steps: int | None, batch: int | None = None) -> tuple[str, ...]:
    """Training length: ``tiny`` trains in minutes on a CPU, ``paper`` for the paper's ~100k steps, ``short``
    the paper's sizes for 1,000 steps × 128 (minutes each on one H100/H200: a ladder that fits a short GPU lease).

    ``short`` is not the paper's schedule: at its lr 1e-4 behind a 500-step warm-up a 1,000-step run barely
    leaves the noise, so it takes lr 5e-4 with a 100-step warm-up and a cosine decay to the end of the run, no
    dropout (a short run underfits), bf16 and the warmed-up EMA (the CPU study's recipe at GPU sizes). One lr
    for every size, as the paper uses one (1e-4) for every size."""
    if preset == "tiny":
        st, bs = steps or 300, batch or 32
        return (f"train.steps={st}", f"train.batch_size={bs}", f"train.log_every={max(st // 12, 1)}",
                f"train.ckpt_every={max(st // 2, 1)}")
    if preset == "short":
        st, bs = steps or 1000, batch or 128
        return (f"train.steps={st}", f"train.batch_size={bs}", f"train.log_every={max(st // 20, 1)}",
                f"train.ckpt_every={st}", "train.bf16=true", "train.optim.lr=5e-4",
                f"train.optim.warmup_steps={min(100, max(st // 10, 1))}", "train.optim.schedule=cosine",
                "model.dropout=0.0")
    if preset == "paper":
        st, bs = steps or 100_000, batch or 256
        return (f"train.steps={st}", f"train.batch_size={bs}", "train.log_every=100", "train.ckpt_every=5000",
                "train.bf16=true")
    raise ValueError(f"unknown preset {preset!r} (tiny | short | paper)")


def data(fraction: float, sampling: str = "clips") -> tuple[str, ...]:
    """Data fraction as nested clip subsets (default) or the reference's (clip, caption level) pairs."""
    if sampling not in ("clips", "pairs"):
        raise ValueError(f"unknown sampling {sampling!r} (clips | pairs)")
    return (f"data.fraction={fraction}",) + (("data.sampling=pairs",) if sampling == "pairs" else ())
