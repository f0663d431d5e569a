"""``handx generate``: sample motion from a trained diffusion run into an official-layout ``.npz``.

Prompt mode (G samples for one prompt; ``--task`` other than text2motion needs ``--source``):

    handx generate --run RUN --left L --right R --interaction I [--samples G] --out gen.npz [--gif gen.gif]
    handx generate --run RUN --task inbetween --source clip.npz [--clip KEY] --out gen.npz
    handx generate --run RUN --task keyframes --keyframes 15,45 --source DATASET --clip ID --out gen.npz
    handx generate --run RUN --task long --left A --right B --interaction C --left A2 ... --out long.npz

Without prompts, a source clip's own annotation at ``--level`` is used. Tasks (paper App. D.2):
inbetween (first/last 5 frames), keyframes (``--keyframes``), wrist (wrist trajectories), reaction
(``--fixed-hand`` fully constrained), long (one segment per repeated --left/--right/--interaction;
continues ``--source`` if given). ``--set diffusion.p_hard=1.0`` etc. change the mask constants.

Batch mode (for evaluation): one prompt per clip of a dataset split, G samples each, entries in clip
order with fields ``source_clip`` (clip id) and ``group`` (0..G−1):

    handx generate --run RUN --reference DIR --split test [--limit N] --samples G --out gen.npz
"""

from __future__ import annotations

import argparse
import time

import numpy as np

# diffusion.TASKS (kept literal so --help does not import JAX; tests check they agree).
TASKS = ("text2motion", "inbetween", "keyframes", "wrist", "reaction", "long")


def _prompts(args) -> list:
    from handx_jax.generation import Prompt

    L, R, I = args.left or [], args.right or [], args.interaction or []
    if not (L or R or I):
        return []
    if not (len(L) == len(R) == len(I)):
        raise ValueError(f"give --left, --right and --interaction the same number of times "
                         f"(got {len(L)}, {len(R)}, {len(I)})")
    from handx_jax.text.prompts import check_texts  # empty prompts are refused (issue 14.8)

    for name, texts in (("--left", L), ("--right", R), ("--interaction", I)):
        check_texts(texts, name)
    return [Prompt(*x) for x in zip(L, R, I)]


def _run(args: argparse.Namespace) -> int:
    from handx_jax.diffusion_family import load_run
    from handx_jax.generation import SampleOptions, generate, generate_long, load_source, write_generated

    if args.task not in ("text2motion", "long") and not (args.source or args.reference):
        print(f"handx generate: error: --task {args.task} needs a constraint clip: --source (or --reference)")
        return 2
    try:
        prompts = _prompts(args)
        run = load_run(args.run, ema=not args.no_ema, encoder=args.encoder, overrides=args.set or [])
    except ValueError as e:
        print(f"handx generate: error: {e}")
        return 2
    opts = SampleOptions(sampler=args.sampler, steps=args.steps, guidance=args.guidance, seed=args.seed,
                         batch_size=args.batch_size)
    keyframes = tuple(int(k) for k in args.keyframes.split(",")) if args.keyframes else (30,)
    t0 = time.perf_counter()
    G = args.samples
    if args.reference:
        if prompts:
            print("handx generate: error: --reference takes its prompts from the dataset; drop --left/--right/...")
            return 2
        from handx_jax.data.dataset import Dataset
        from handx_jax.generation import Prompt

        ds = Dataset.open(args.reference)
        clips = np.asarray(ds.split(args.split))
        if args.limit and args.limit < len(clips):  # the reference's selection: shuffle (seed 42), take N, sort
            clips = np.sort(np.random.default_rng(42).permutation(clips)[:args.limit])
        ps = [Prompt(*(ds.texts[c][f][args.level] for f in ("left", "right", "interaction"))) for c in clips]
        sources = [np.asarray(ds.motion[c], np.float32) for c in clips]
        j = generate(run, ps, opts, samples=G, task=args.task, sources=sources, keyframes=keyframes,
                     fixed_hand=args.fixed_hand)
        ids = [ds.ids[c] for c in clips]
        write_generated(args.out, j.reshape(-1, *j.shape[2:]), [[p] for p in ps for _ in range(G)],
                        source_clips=[i for i in ids for _ in range(G)], groups=[g for _ in ids for g in range(G)])
        n = len(ps) * G
        first, first_prompt = j[0, 0], ps[0]
    else:
        src = load_source(args.source, args.clip) if args.source else None
        if not prompts:
            if src is None:
                print("handx generate: error: give --left/--right/--interaction, a --source clip, or --reference")
                return 2
            prompts = [src.prompts[args.level]]
        if args.task == "long":
            j = generate_long(run, prompts, opts, samples=G, source=None if src is None else src.joints)
            write_generated(args.out, j, [prompts] * G, groups=list(range(G)),
                            source_clips=[src.key if src else None] * G)
            first, first_prompt = j[0], prompts[0]
        else:
            if len(prompts) != 1:
                print(f"handx generate: error: task {args.task} takes one prompt, got {len(prompts)}")
                return 2
            j = generate(run, prompts, opts, samples=G, task=args.task,
                         sources=None if src is None else [src.joints], keyframes=keyframes, fixed_hand=args.fixed_hand)
            write_generated(args.out, j[0], [prompts] * G, groups=list(range(G)),
                            source_clips=[src.key if src else None] * G)
            first, first_prompt = j[0, 0], prompts[0]
        n = G
    dt = time.perf_counter() - t0
    print(f"wrote {args.out}: {n} motion(s), task {args.task}, {args.sampler}"
          f"{'-' + str(args.steps) if args.sampler == 'ddim' else ''}, guidance "
          f"{run.cfg.diffusion.guidance if args.guidance is None else args.guidance}, "
          f"{'EMA' if run.used_ema else 'raw'} params at step {run.step}, {dt:.1f} s")
    if args.gif:
        from handx_jax.data.render import render_gif

        render_gif(first, args.gif, texts=first_prompt.texts())
        print(f"wrote {args.gif}")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("generate", help="sample motion from a trained diffusion run",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", required=True, help="diffusion run folder")
    p.add_argument("--left", action="append", help="left-hand prompt (repeat for --task long); prompts must not "
                                                   "be empty (refused: no model was trained on an empty caption)")
    p.add_argument("--right", action="append", help="right-hand prompt")
    p.add_argument("--interaction", action="append", help="interaction prompt")
    p.add_argument("--task", default="text2motion", choices=TASKS)
    p.add_argument("--source", help="constraint clip: official-layout .npz or a dataset directory (with --clip)")
    p.add_argument("--clip", help="key in the .npz, or clip id/index in the dataset")
    p.add_argument("--level", type=int, default=-1, help="annotation level for prompts taken from data (-1 = most detailed)")
    p.add_argument("--keyframes", help="comma-separated keyframe indices for --task keyframes (default 30)")
    p.add_argument("--fixed-hand", default="left", choices=["left", "right"], help="constrained hand for reaction")
    p.add_argument("--reference", help="batch mode: dataset directory; one prompt per clip of --split")
    p.add_argument("--split", default="test", choices=["train", "val", "test"])
    p.add_argument("--limit", type=int, help="batch mode: at most N clips (shuffled with seed 42, then sorted)")
    p.add_argument("--samples", type=int, default=1, help="samples per prompt (G)")
    p.add_argument("--sampler", default="ddpm", choices=["ddpm", "ddim"])
    p.add_argument("--steps", type=int, default=50, help="DDIM steps (DDPM always uses all T steps)")
    p.add_argument("--guidance", type=float, help="CFG scale (default: the run's, 2.5)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch-size", type=int, default=256, help="samples per compiled sampler call")
    p.add_argument("--no-ema", action="store_true", help="use the raw (not EMA) parameters")
    p.add_argument("--encoder", help="encoder folder (default: the one the run was trained with)")
    p.add_argument("--set", action="append", metavar="diffusion.KEY=VALUE",
                   help="override diffusion settings, e.g. diffusion.p_hard=1.0, diffusion.blend=xt")
    p.add_argument("--out", required=True, help="output .npz (official layout)")
    p.add_argument("--gif", help="also render the first sample as a GIF")
    p.set_defaults(func=_run)
    return p
