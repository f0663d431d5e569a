"""A CPU diffusion scaling study that means something: model size × data fraction at fixed epochs
(``make sweep-cpu``; the short ``demo`` preset is ``make demo``'s mini sweep).

    handx sweep run sweeps/diffusion_cpu_study.py --preset matched --data D --encoder E --evaluator standard \\
        --eval-limit 10000 --eval-samples 4 --set sample.steps=25 --max-parallel 2 --out runs/sweep-cpu
    handx analyze fit runs/sweep-cpu/results.csv --x compute --y rprec_top3 --plot fit.png

Why it looks like this (issue 13 item 7). The earlier CPU grids trained every model for 60-300 steps
at the tiny preset's lr 1e-4 behind a 500-step warm-up, so no run left the chance level (3/32 top-3
at block 32) and the fit was noise. A text-to-motion model needs thousands of optimizer steps before
the evaluator can tell which caption produced a motion, and two CPU cores give about an hour. So:

* **Small, fast denoisers** (``SIZES``): three widths/depths whose per-sample FLOPs span ~10×, all
  cheap enough on one core to take thousands of steps; no dropout (they underfit, they do not
  overfit), lr 1e-3 with a short warm-up and a cosine decay to the end of each run, EMA weights for
  sampling (``train.ema_warmup``, so short runs use them too).
* **Fixed epochs, the data axis as Table 2's** (``FRACTIONS``, nested clip subsets 20% ⊂ 100% of the
  corpus's train split, ``data.sampling=clips``): every run sees each of its training items the same
  number of times, so a run on 20% of the clips takes 20% of the steps. Training compute
  (``train_flops`` = 3 × forward FLOPs × samples seen) then spans sizes × fractions, ~50× here, and
  the study's x axis is training compute (``handx analyze fit --x compute``). This is the CPU analogue
  of the paper's Fig. 4 / Table 2 reading — more compute, through a larger model or more data at the
  same number of epochs, gives better text-motion alignment — at sizes a CPU trains in minutes. (The
  paper's Fig. 4 x axis is per-sample FLOPs at a fixed number of iterations, which is proportional to
  training compute there; here the step count differs between fractions, so per-sample FLOPs alone
  would put two runs of different compute on one x value.) Each row also carries the per-sample FLOPs
  in both conventions, so ``--x flops`` is one flag away.
* **Scoring**: the packaged standard evaluator on the corpus's standard test prompts, G samples per
  prompt (the ± is then a Student-t interval over the G generation groups, ``metrics.ci_method``;
  ``make sweep-cpu`` uses G = 4: at G = 2 it has one degree of freedom, t = 12.7, and says nothing),
  DDIM with fewer steps than the 50 default (a generation option; the same for every run, so it moves
  every score alike).

* **Steps growing with size** (``matched``, ``make sweep-cpu``): ``cpu`` gives every size the same steps;
  there, a decade of samples seen bought about twice the top-3 of a decade of per-sample FLOPs
  (``handx analyze factors``), so compute spent on width alone fell under the line (r 0.873).
  ``matched`` doubles the steps with each size (``SIZE_STEPS``), so data seen grows with capacity, as
  the paper's "matched increases in data and capacity" and a compute-optimal allocation do (r 0.949;
  docs/results/cpu_study).

Run ids are deterministic (``run_id``: the axis values, then a hash of every override).
"""

from __future__ import annotations

from sweeps.diffusion_common import RESOURCES as _RESOURCES, data, model
from sweeps.launcher import RunSpec, axes_of, run_id

# (layers, dim, heads, FFN): per-sample forward FLOPs (analytic) ≈ 12 M, 55 M, 177 M.
SIZES = ((1, 32, 2, 64), (2, 64, 4, 128), (2, 128, 4, 256))
# make demo: the study's sizes at the steps of its 20% runs (150 / 300 / 600), on all the prefix's train clips.
# Its first design (L1 d32, L2 d48, L2 d64, 400 steps each, 76 test prompts of a 1,200-clip prefix) ended with
# a falling fit under evaluator v4 (top-3 0.170 / 0.083 / 0.136, slope -0.070 per decade: issue 31): at equal
# steps the sizes were within the scores' ± of each other. With data seen growing with size (as ``matched``)
# and the 230 test prompts of a 4,000-clip prefix, 4 samples each, the fit rises: top-3 0.097 / 0.088 / 0.146
# (± 0.029 / 0.016 / 0.015), slope +0.025 per decade, r 0.75 (2026-11-27, seed 42).
DEMO_SIZES = SIZES
FRACTIONS = (0.2, 1.0)
# Optimizer steps at data fraction 1.0 per preset; fraction f trains round(f × STEPS) steps (fixed epochs).
STEPS = {"cpu": 1500, "demo": 300, "matched": 1500}
# ``matched``: the steps also grow with model size, ×0.5 / ×1 / ×2 over SIZES (about ∝ √ per-sample FLOPs),
# so that training data seen grows with capacity, as the paper's closing reading asks ("matched increases in
# data and capacity", Sec. 6.3) and as a compute-optimal allocation would. Why it exists: at fixed steps per
# fraction (``cpu``), a decade of samples seen bought about twice the top-3 of a decade of per-sample FLOPs
# (``handx analyze factors``, docs/results/cpu_study), so compute spent on width alone sat below the line.
SIZE_STEPS = {"matched": (0.5, 1.0, 2.0), "demo": (0.5, 1.0, 2.0)}
BATCH = 32
RESOURCES = {**_RESOURCES, "cpu": {"timeout_min": 90, "cpus_per_task": 1, "mem_gb": 4},
             "demo": {"timeout_min": 30, "cpus_per_task": 1, "mem_gb": 4},
             "matched": {"timeout_min": 120, "cpus_per_task": 1, "mem_gb": 4}}


def _train(steps: int, batch: int) -> tuple[str, ...]:
    return (f"train.steps={steps}", f"train.batch_size={batch}", f"train.log_every={max(steps // 10, 1)}",
            f"train.ckpt_every={steps}", "train.optim.lr=1e-3", f"train.optim.warmup_steps={min(100, steps // 10)}",
            "train.optim.schedule=cosine", "model.dropout=0.0", "train.wandb=disabled")


def runs(preset: str = "cpu", steps: int | None = None, batch: int = BATCH, fractions: tuple = FRACTIONS,
         sizes: tuple | None = None, seeds: tuple | int | None = None) -> list[RunSpec]:
    """The study's runs, most expensive first (so ``--max-parallel 2`` packs two cores well).

    ``preset``: ``cpu`` (``make sweep-cpu``), ``matched`` (``cpu``'s grid, steps growing with size:
    ``SIZE_STEPS``) or ``demo`` (``make demo``: ``DEMO_SIZES`` on the largest fraction only, steps growing
    with size as ``matched``'s, at ``STEPS["demo"]``);
    ``steps`` overrides the steps at fraction 1.0 (of the middle size, for ``matched``); ``seeds``, one
    training seed or several (initialisation and data order; default the trainer's 42), for replicates of
    the study: every configuration is trained once per seed (``handx analyze fit --mean-replicates``). The
    trainer's default seed adds no override, so its runs keep the ids of a launch without ``seeds``."""
    if preset not in STEPS:
        raise ValueError(f"unknown preset {preset!r} ({' | '.join(STEPS)})")
    full = int(steps or STEPS[preset])
    fracs = tuple(float(f) for f in ((max(fractions),) if preset == "demo" else fractions))
    sizes = sizes or (DEMO_SIZES if preset == "demo" else SIZES)
    scale = SIZE_STEPS.get(preset, (1.0,) * len(sizes))
    if len(scale) != len(sizes):
        raise ValueError(f"preset {preset!r} scales the steps of {len(scale)} sizes, got {len(sizes)} sizes")
    from handx_jax.train import TrainConfig

    seeds = (TrainConfig.seed,) if seeds is None else (seeds,) if isinstance(seeds, int) else tuple(seeds)
    if len(set(seeds)) != len(seeds) or not all(isinstance(x, int) and not isinstance(x, bool) for x in seeds):
        raise ValueError(f"seeds must be distinct whole numbers, got {seeds!r}")
    out = []
    for seed in seeds:
        for frac in fracs:
            for (L, d, H, F), k in zip(sizes, scale):
                st = max(int(round(full * k * frac / max(fracs))), 1)
                ov = (*model(L, d, H, F), *data(frac), *_train(st, int(batch)),
                      *(() if seed == TrainConfig.seed else (f"train.seed={seed}",)))
                axes = axes_of(ov, "layers", "dim", "data_fraction")
                out.append(RunSpec(run_id(axes, ov), "diffusion", preset="tiny", overrides=ov, axes=axes))
    # training cost ∝ steps × per-sample FLOPs; run the largest first
    return sorted(out, key=lambda s: -_cost(s))


def _cost(spec: RunSpec) -> float:
    """Steps × the denoiser's analytic forward FLOPs per sample (~40 text tokens): enough to order the runs."""
    from handx_jax.models.dit import DiTConfig, forward_flops

    o = dict(x.split("=", 1) for x in spec.overrides)
    cfg = DiTConfig(layers=int(o["model.layers"]), dim=int(o["model.dim"]), heads=int(o["model.heads"]),
                    ff=int(o["model.ff"]))
    return int(o["train.steps"]) * forward_flops(cfg, text_len=40)
