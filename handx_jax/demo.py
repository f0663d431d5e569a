"""``make demo``: the main job, end to end, on the built-in data (CPU-sized: 598 s on 2 quiet cores from a fresh
clone, install included, under evaluator v8 on corpus v5; README).

1. Build the first ``--clips`` clips of the standard corpus (``handx standard corpus --clips N``: synthesis
   → clips + intensity filter → annotation → captions), print its statistics and render one clip with
   its texts as a GIF. Being a prefix of the standard corpus, its test split is the first test clips of
   the standard one and its train split holds no standard test clip (``handx_jax/standard/``).
2. Text side: the packaged tokenizer and tiny T5 (``handx standard info``) encode every caption once.
3. Score the test split's ground truth with the packaged standard evaluator (no evaluator is trained).
4. A mini scaling sweep (``handx sweep run``, the ``demo`` preset of ``sweeps/diffusion_cpu_study.py``,
   the short version of ``make sweep-cpu``): the study's three sizes (L1 d32, L2 d64, L2 d128) trained for
   150 / 300 / 600 steps (data seen growing with size, as the study's ``matched`` design) at lr 1e-3, two at
   a time, each sampled 4 times for all the prefix's 205 standard test prompts (DDIM, 25 steps) and scored
   by the standard evaluator; then the log-linear fit of top-3 R-Precision against training compute and
   its plot, with the chance level drawn, and a verdict: does the curve rise, beside the committed
   ``make sweep-cpu`` curve. Measured (seed 42, evaluator v8 on corpus v5): top-3 0.116 / 0.147 / 0.161,
   slope +0.024 per decade (95% CI [0.018, 0.031]), r 0.990; the largest run's interval [0.124, 0.198] is
   above chance (0.094). The ground truth's own row has inter-hand Pen 1cm 0.000 % (corpus v4 under v7: 9.5 %).

Each stage is the same ``handx`` command a user would run (printed before it runs). The models are
small and trained for a few minutes, so the sweep shows the pipeline and how to read a fit, not the
paper's numbers (``make sweep-cpu`` trains longer: ``docs/results/cpu_study/``); ``--data-only`` stops
after stage 1.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _handx(*args: str) -> None:
    print(f"\n$ handx {' '.join(shlex.quote(a) for a in args)}", flush=True)
    subprocess.run([sys.executable, "-m", "handx_jax", *args], check=True)


def data_stage(out: Path, clips: int) -> Path:
    from handx_jax.annotation.caption import build_prompt
    from handx_jax.dataset.format import Dataset
    from handx_jax.dataset.render import render_gif
    from handx_jax.dataset.stats import dataset_stats, format_stats
    from handx_jax.infra.atomic import atomic_write_json, atomic_write_text
    from handx_jax.standard import build_standard_corpus

    t0 = time.perf_counter()
    print(f"\n$ handx standard corpus --clips {clips} --out {out / 'data'}", flush=True)
    data_dir = build_standard_corpus(out / "data", clips, overwrite=True)
    ds = Dataset.open(data_dir)
    print(f"\n== corpus: {data_dir} ({len(ds)} clips, built in {time.perf_counter() - t0:.1f} s)")
    rep = ds.report["clips"]
    print(f"cut report: {rep['sequences']} sequences, {rep['windows']} windows; defective frames "
          f"{rep['defective_frames']}; rejected by intensity {rep['rejected_intensity']}; kept {rep['kept']}")
    st = dataset_stats(ds)
    print(format_stats(st))
    atomic_write_json(out / "stats.json", st)

    i = int(np.argmax([len(t["interaction"][-1]) for t in ds.texts[:50]]))  # a clip with a rich interaction
    t = ds.texts[i]
    print(f"\n== clip {t['id']}: captions by level")
    for lv in range(len(t["left"])):
        print(f"[L{lv}] left: {t['left'][lv]}\n      right: {t['right'][lv]}\n      both: {t['interaction'][lv]}")
    gif = render_gif(np.asarray(ds.motion[i]), out / "clip.gif",
                     texts=(t["left"][0], t["right"][0], t["interaction"][0]), title=t["id"])
    atomic_write_text(out / "prompt.txt", build_prompt(ds.events[i]))
    print(f"\nwrote {gif}, {out / 'prompt.txt'} (LLM prompt for that clip), {out / 'stats.json'}")
    return data_dir


SWEEP = Path(__file__).resolve().parent.parent / "sweeps" / "diffusion_cpu_study.py"


def model_stages(out: Path, data: Path, steps: int | None, eval_limit: int, eval_samples: int = 1,
                 sampler_steps: int = 25) -> None:
    from handx_jax.standard import encoder_dir, evaluator_dir

    enc, sweep = str(encoder_dir()), out / "sweep"
    _handx("standard", "info")
    _handx("text", "cache", "--data", str(data), "--encoder", enc, "--nn-check", "500")
    _handx("eval", "run", "--ground-truth", "--data", str(data), "--replications", "10")
    # The short version of `make sweep-cpu` (sweeps/diffusion_cpu_study.py, preset demo): its three sizes on all
    # the prefix's train clips, steps growing with size, two runs at a time, each scored by the standard evaluator.
    _handx("sweep", "run", str(SWEEP), "--preset", "demo", *(("--arg", f"steps={steps}") if steps else ()),
           "--data", str(data), "--encoder", enc, "--evaluator", str(evaluator_dir()), "--eval-limit", str(eval_limit),
           "--eval-samples", str(eval_samples), "--set", f"sample.steps={sampler_steps}", "--max-parallel", "2",
           "--out", str(sweep))
    _handx("analyze", "table", str(sweep / "results.jsonl"))
    # x = training compute: the study trains at fixed epochs (see the sweep file's docstring)
    _handx("analyze", "fit", str(sweep / "results.jsonl"), "--x", "compute", "--y", "rprec_top3",
           "--plot", str(sweep / "fit.png"))
    verdict(sweep, out)
    runs = sorted((sweep / "runs").glob("*/generated.npz"))
    if runs:
        from handx_jax.interop.handx_npz import read_handx_npz
        from handx_jax.dataset.render import render_gif

        clip = read_handx_npz(runs[-1])[0]
        gif = render_gif(clip.motion, out / "generated.gif", texts=(clip.left[0], clip.right[0], clip.interaction[0]),
                         title=runs[-1].parent.name)
        print(f"wrote {gif} (first generated clip of {runs[-1].parent.name})")
    print(f"\nresults: {sweep / 'results.jsonl'} (one row per run), fit plot: {sweep / 'fit.png'}")


# The committed `make sweep-cpu` studies, one folder per standard evaluator (vN: one seed; vN/replicates: three
# seeds, fit on the means): the curve the demo's mini sweep is the short version of (docs/results/cpu_study/).
STUDIES = Path(__file__).resolve().parent.parent / "docs" / "results" / "cpu_study"


def committed_study() -> tuple[Path | None, int | None]:
    """(folder, evaluator version) of the committed study under the current standard evaluator (its three-seed
    replicates where committed, else its one-seed study), else the newest one under an earlier evaluator (the
    demo then says it is another yardstick)."""
    from handx_jax import standard

    found = []
    for p in STUDIES.glob("v*"):
        if p.name[1:].isdigit():
            best = next((q for q in (p / "replicates", p) if (q / "fit.txt").exists()), None)
            if best is not None:
                found.append((int(p.name[1:]), best))
    found.sort()
    same = [(v, p) for v, p in found if v == standard.VERSION]
    v, p = (same or found or [(None, None)])[-1]
    return p, v


def rises(rows: list[dict], fit: dict) -> tuple[bool, str]:
    """Whether a sweep's fit shows the scaling (issue 31 item 4): a positive slope and the largest run's
    top-3 interval above chance (k/block), with the numbers that decide it."""
    from analysis.fits import chance_level

    big = max(rows, key=lambda r: r["train_flops"])
    chance = chance_level("rprec_top3", block=big["rprec_block"])
    lo = big["rprec_top3"] - big["rprec_top3_ci"]
    ok = fit["slope"] > 0 and lo > chance
    return ok, (f"slope {fit['slope']:+.4f} per decade (95% CI [{fit['slope_ci'][0]:.4f}, {fit['slope_ci'][1]:.4f}]), "
                f"r {fit['r']:.3f}; largest run {big['run_id']}: top-3 {big['rprec_top3']:.3f} "
                f"± {big['rprec_top3_ci']:.3f} (lower end {lo:.3f}, chance {chance:.3f})")


def verdict(sweep: Path, out: Path) -> bool:
    """Say whether the mini sweep's curve rises, and show the committed `make sweep-cpu` curve beside it."""
    import json
    import shutil

    from handx_jax.infra.readers import read_jsonl

    r = subprocess.run([sys.executable, "-m", "handx_jax", "analyze", "fit", str(sweep / "results.jsonl"), "--x",
                        "compute", "--y", "rprec_top3", "--json"], check=True, capture_output=True, text=True)
    from handx_jax import standard

    ok, why = rises(read_jsonl(sweep / "results.jsonl"), json.loads(r.stdout))
    print(f"\n== the demo's curve {'rises' if ok else 'does NOT rise'}: {why}")
    STUDY, version = committed_study()
    if STUDY is not None:
        same = version == standard.VERSION
        yardstick = ("same evaluator" if same else
                     f"scored by standard evaluator v{version}, NOT this demo's v{standard.VERSION}: another yardstick, "
                     f"so compare its shape, not its numbers")
        shutil.copyfile(STUDY / "fit.png", out / "sweep-cpu-fit.png")
        # Issue 31 item 4. The first design (133 s of sweep) fell (r -0.60); this one rises (575 s from a fresh
        # clone, install included), but its slope's interval still holds 0. Say so, and show the study.
        print(("" if ok else "This sweep's curve does not show the scaling on this yardstick; ")
              + "a mini sweep short enough for 10 minutes on 2 cores is too noisy to pin the slope down (this "
              "demo takes 10 min with its install on 2 quiet cores under v8, measured; 5 min 44 s under v7); the committed `make sweep-cpu` study "
              f"(6 configurations x {'3 seeds' if STUDY.name == 'replicates' else 'one seed'}, ~20 min per seed, "
              f"{yardstick}; {STUDY.relative_to(STUDIES.parents[2])}) gives, beside the demo's:\n"
              + "".join("    " + ln + "\n" for ln in (STUDY / "fit.txt").read_text().splitlines()[:5])
              + f"its plot: {out / 'sweep-cpu-fit.png'}; the demo's: {sweep / 'fit.png'}")
    return ok


def main(argv: list[str] | None = None) -> int:
    import textwrap

    from handx_jax.dataset.clips import defect_reasons_help

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=textwrap.fill("The corpus cut report (stage 1): " + defect_reasons_help(), 100))
    p.add_argument("--out", default="runs/demo", help="demo folder (rebuilt each time)")
    # 4,000 clips: 230 standard test prompts, so the scores' ± (≈ 0.015-0.03 with 4 samples each) is below the
    # differences between the sizes; 1,200 clips gave 76 prompts and ± 0.05-0.08, wider than those differences
    p.add_argument("--clips", type=int, default=4000, help="first N clips of the standard corpus")
    p.add_argument("--steps", type=int,
                   help="training steps of the middle size (the others x0.5 and x2; default: the demo preset's 300)")
    p.add_argument("--eval-limit", type=int, default=10000, help="test prompts generated and scored per run")
    p.add_argument("--eval-samples", type=int, default=4,
                   help="samples per test prompt (the ± is a t-interval over the groups; 1: a prompt bootstrap)")
    p.add_argument("--sampler-steps", type=int, default=25, help="DDIM steps when sampling the test prompts")
    p.add_argument("--data-only", action="store_true", help="stop after building and inspecting the corpus")
    a = p.parse_args(argv)
    os.environ.setdefault("WANDB_MODE", "disabled")
    out = Path(a.out)
    if out.exists():  # the demo folder is scratch space: rebuilt from nothing each time
        import shutil

        shutil.rmtree(out)
    t0 = time.perf_counter()
    data = data_stage(out, a.clips)
    if not a.data_only:
        model_stages(out, data, a.steps, a.eval_limit, a.eval_samples, a.sampler_steps)
    print(f"\ndemo finished in {time.perf_counter() - t0:.0f} s; everything is in {out}/")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
