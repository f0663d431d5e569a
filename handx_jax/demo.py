"""``make demo``: the main job, end to end, on the built-in data (CPU-sized, a few minutes).

1. Build a small procedural corpus (synthesis → clips + intensity filter → annotation → captions),
   print its statistics and render one clip with its texts as a GIF.
2. Train the text side: SentencePiece tokenizer, a tiny T5 by span corruption, the embedding caches.
3. Train a tiny treble-residual diffusion model and a tiny contrastive evaluator.
4. Generate motion for the test split and score it against the ground truth (paper Table 2 layout).

Each stage is the same ``handx`` command a user would run (printed before it runs). Sizes are tiny, so
the scores only show that the pipeline runs; ``--data-only`` stops after stage 1.
"""

from __future__ import annotations

import argparse
import json
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


def data_stage(out: Path, clips: int, seed: int) -> Path:
    from handx_jax.data.build import BuildConfig, build_corpus
    from handx_jax.data.caption import build_prompt
    from handx_jax.data.dataset import Dataset
    from handx_jax.data.render import render_gif
    from handx_jax.data.stats import dataset_stats, format_stats
    from handx_jax.io import atomic_write_json, atomic_write_text

    t0 = time.perf_counter()
    data_dir = build_corpus(out / "data", BuildConfig(clips=clips, seed=seed), overwrite=True)
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


def model_stages(out: Path, data: Path, steps: int) -> None:
    t5, run, ev = out / "t5", out / "diffusion", out / "evaluator"
    enc = str(t5 / "encoder")
    _handx("text", "tokenizer", "--data", str(data), "--force")
    _handx("text", "pretrain", "--data", str(data), "--preset", "tiny", "--out", str(t5), "--steps", str(steps),
           "--eval-every", str(steps), "--ckpt-every", str(steps))
    _handx("text", "cache", "--data", str(data), "--encoder", enc, "--nn-check", "500")
    _handx("train", "diffusion", "--data", str(data), "--encoder", enc, "--preset", "tiny", "--out", str(run),
           "--set", f"train.steps={2 * steps}", "--set", "train.batch_size=32", "--set", f"train.log_every={steps // 4}",
           "--set", f"train.ckpt_every={steps}", "--set", "train.optim.lr=1e-3", "--set", "train.optim.warmup_steps=50",
           "--quiet")
    _handx("eval", "train-evaluator", "--data", str(data), "--encoder", enc, "--out", str(ev), "--preset", "tiny",
           "--steps", str(2 * steps), "--batch-size", "32", "--lr", "1e-3", "--train-levels", "1", "--eval-level", "1")
    _handx("generate", "--run", str(run), "--reference", str(data), "--split", "test", "--level", "1",
           "--samples", "2", "--sampler", "ddim", "--steps", "25", "--out", str(out / "generated.npz"),
           "--gif", str(out / "generated.gif"))
    _handx("eval", "run", "--evaluator", str(ev), "--generated", str(out / "generated.npz"), "--reference", str(data),
           "--replications", "10", "--out", str(run))
    _handx("eval", "run", "--evaluator", str(ev), "--ground-truth", "--reference", str(data), "--replications", "10")
    row = json.loads((run / "eval.json").read_text())
    print(f"\nwrote {run}/eval.json; the run folder is one row of a results table "
          f"(`handx analyze table {run}`): rprec_top3 = {row.get('rprec_top3')}")


def main(argv: list[str] | None = None) -> int:
    import textwrap

    from handx_jax.data.clips import defect_reasons_help

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=textwrap.fill("The corpus cut report (stage 1): " + defect_reasons_help(), 100))
    p.add_argument("--out", default="runs/demo", help="demo folder (rebuilt each time)")
    p.add_argument("--clips", type=int, default=600)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=200, help="T5 pretraining steps (generator/evaluator: twice this)")
    p.add_argument("--data-only", action="store_true", help="stop after building and inspecting the corpus")
    a = p.parse_args(argv)
    os.environ.setdefault("WANDB_MODE", "disabled")
    out = Path(a.out)
    if out.exists():  # the demo folder is scratch space: rebuilt from nothing each time
        import shutil

        shutil.rmtree(out)
    t0 = time.perf_counter()
    data = data_stage(out, a.clips, a.seed)
    if not a.data_only:
        model_stages(out, data, a.steps)
    print(f"\ndemo finished in {time.perf_counter() - t0:.0f} s; everything is in {out}/")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
