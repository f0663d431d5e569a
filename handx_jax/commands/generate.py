"""``handx generate``: sample motion from a trained run (any family) into an official-layout ``.npz``.

Prompt mode (G samples for one prompt; ``--task`` other than text2motion needs ``--source``):

    handx generate --run RUN --left L --right R --interaction I [--samples G] --out gen.npz [--gif gen.gif]
    handx generate --run RUN --task inbetween --source clip.npz [--clip KEY] --out gen.npz
    handx generate --run RUN --task keyframes --keyframes 15,45 --source DATASET --clip ID --out gen.npz
    handx generate --run RUN --task long --left A --right B --interaction C --left A2 ... --out long.npz

Without prompts, a source clip's own annotation at ``--level`` is used. Tasks (paper App. D.2):
inbetween (first/last 5 frames), keyframes (``--keyframes``), wrist (wrist trajectories), reaction
(``--fixed-hand`` fully constrained), long (one segment per repeated --left/--right/--interaction;
continues ``--source`` if given), and prediction (the source's first ``--observed-frames`` frames are
observed, the rest generated; scored by ``handx eval prediction``). A family may support only some
tasks. Generation settings are the run's own config (its ``sample.*`` keys), changed with ``--set
sample.KEY=VALUE`` for any family (the sweep launcher's one channel); the run's family adds flags for
the same keys: ``handx generate --run RUN --help`` lists them (for diffusion ``--sampler``,
``--sample-steps``, ``--guidance``; ``--set diffusion.p_hard=1.0`` etc.).

Batch mode (for evaluation): one prompt per clip of a dataset split, G samples each, entries in clip
order with fields ``source_clip`` (clip id) and ``group`` (0..G−1):

    handx generate --run RUN --data DIR --split test [--limit N] --samples G --out gen.npz

Object to motion (a family whose task it is, BimArt): hands for an object and its trajectory, from a hand-object
corpus or an ARCTIC sequence, written with the object's state beside them (``handx eval objects`` scores them):

    handx generate --run RUN --task object2motion --data OBJ [--split test --limit N | --clip N] --out gen.npz
    handx generate --run RUN --task object2motion --arctic ROOT --seq s01/box_use_01 [--start F] --out gen.npz
"""

from __future__ import annotations

import argparse
import time

from handx_jax.cliargs import deprecated_flag
from handx_jax.commands import fail

CMD = "handx generate"


def _check_empty(args) -> None:
    """Empty prompts are refused (issue 14.8): no model was trained on an empty caption."""
    from handx_jax.text.prompts import check_texts

    for name, texts in (("--left", args.left), ("--right", args.right), ("--interaction", args.interaction)):
        check_texts(texts or [], name)


def _prompts(args) -> list:
    from handx_jax.generation import Prompt

    L, R, I = args.left or [], args.right or [], args.interaction or []
    if not (L or R or I):
        return []
    if not (len(L) == len(R) == len(I)):
        raise ValueError(f"give --left, --right and --interaction the same number of times "
                         f"(got {len(L)}, {len(R)}, {len(I)})")
    _check_empty(args)
    return [Prompt(*x) for x in zip(L, R, I)]


def family_parser(run: str):
    """(family module, parser of its options): the options the shared parser did not know."""
    from handx_jax.families import family_of, get_family

    name = family_of(run)
    fam = get_family(name)
    p = argparse.ArgumentParser(prog=f"{CMD} --run {run}", add_help=False, allow_abbrev=False)
    fam.add_generate_args(p.add_argument_group(f"{name} options"))
    return fam, p


def _run(args: argparse.Namespace) -> int:
    try:
        return _generate(args)
    except ValueError as e:  # DataError too: a bad option, prompt, clip or source is one line (issue 31)
        return fail(CMD, e)


def _generate(args: argparse.Namespace) -> int:
    if not args.run:
        args.parser.print_help()
        print("\nfamily options: see `handx generate --run RUN --help`")
        return 0 if args.help else fail(CMD, "the following arguments are required: --run, --out")
    try:
        if not args.help:
            _check_empty(args)  # before any run is opened
        fam, fp = family_parser(args.run)
    except ValueError as e:
        return fail(CMD, e)
    if args.help:
        args.parser.print_help()
        print()
        fp.print_help()
        return 0
    if not args.out:
        return fail(CMD, "the following arguments are required: --out")
    from handx_jax.generation import check_limit

    check_limit(args.limit)
    from handx_jax.generation import load_source, write_generated

    fargs = fp.parse_args(args.extra, namespace=argparse.Namespace(**vars(args)))
    try:
        from handx_jax.families import check_task, family_of

        check_task(family_of(args.run), args.task)  # before the run is read (families.check_task)
    except ValueError as e:
        return fail(CMD, e)
    if args.task != "prediction" and any(a.split("=", 1)[0] == "--observed-frames" for a in args.extra):
        return fail(CMD, f"--observed-frames is read by --task prediction only (the observed start of each clip); "
                         f"--task {args.task} would ignore it")
    if args.task == "object2motion":  # its inputs checked before the run is read
        problem = _object_args_problem(args)
        if problem:
            return fail(CMD, problem)
    elif args.task not in ("text2motion", "long") and not (args.source or args.data):
        return fail(CMD, f"--task {args.task} needs a constraint clip: --source (or --data)")
    try:
        prompts = _prompts(args)
        run, opts = fam.load_for_generate(fargs, ema=not args.no_ema, encoder=args.encoder, seed=args.seed,
                                          batch_size=args.batch_size)
    except ValueError as e:
        return fail(CMD, e)
    if args.task not in run.tasks:
        return fail(CMD, f"family {fam.FAMILY} does not do --task {args.task}; it does {', '.join(run.tasks)}")
    keyframes = tuple(int(k) for k in args.keyframes.split(",")) if args.keyframes else (30,)
    t0 = time.perf_counter()
    G = args.samples
    if args.task == "object2motion":  # an object and its trajectory (a corpus clip, an ARCTIC sequence), no prompt
        return _object2motion(args, run, opts, t0)
    if args.data:
        if prompts:
            return fail(CMD, "--data takes its prompts from the dataset; drop --left/--right/...")
        from handx_jax.dataset.format import Dataset
        from handx_jax.generation import split_prompts

        ds = Dataset.open(args.data)
        clips, ps, sources = split_prompts(ds, args.split, args.limit, args.level)
        if getattr(opts, "needs_records", False):  # the sampler reads each prompt's record (contact guidance)
            from handx_jax.generation import with_records

            ps = with_records(ps, ds, clips)
        j = run.generate(ps, opts, samples=G, task=args.task, sources=sources, keyframes=keyframes,
                         fixed_hand=args.fixed_hand)
        ids = [ds.ids[c] for c in clips]
        write_generated(args.out, j.reshape(-1, *j.shape[2:]), [[p] for p in ps for _ in range(G)],
                        source_clips=[i for i in ids for _ in range(G)], groups=[g for _ in ids for g in range(G)])
        n = len(ps) * G
        first, first_prompt = j[0, 0], ps[0]
    else:
        records = getattr(opts, "needs_records", False)
        src = load_source(args.source, args.clip, records=records) if args.source else None
        if not prompts:
            if src is None:
                return fail(CMD, "give --left/--right/--interaction, a --source clip, or --data")
            from handx_jax.generation import check_level

            check_level(args.level, len(src.prompts), args.source)
            prompts = [src.prompts[args.level]]
        if args.task == "long":
            j = run.generate_long(prompts, opts, samples=G, source=None if src is None else src.joints)
            write_generated(args.out, j, [prompts] * G, groups=list(range(G)),
                            source_clips=[src.key if src else None] * G)
            first, first_prompt = j[0], prompts[0]
        else:
            if len(prompts) != 1:
                return fail(CMD, f"task {args.task} takes one prompt, got {len(prompts)}")
            j = run.generate(prompts, opts, samples=G, task=args.task, sources=None if src is None else [src.joints],
                             keyframes=keyframes, fixed_hand=args.fixed_hand)
            write_generated(args.out, j[0], [prompts] * G, groups=list(range(G)),
                            source_clips=[src.key if src else None] * G)
            first, first_prompt = j[0, 0], prompts[0]
        n = G
    dt = time.perf_counter() - t0
    print(f"wrote {args.out}: {n} motion(s), task {args.task}, {run.describe(opts)}, {dt:.1f} s")
    if args.gif:
        from handx_jax.dataset.render import render_gif

        render_gif(first, args.gif, texts=first_prompt.texts())
        print(f"wrote {args.gif}")
    return 0


def _object_args_problem(args) -> str | None:
    if args.left or args.right or args.interaction or bool(args.data) == bool(args.arctic):
        return ("--task object2motion takes its objects and trajectories from a hand-object corpus (--data CORPUS "
                "with --split/--limit or --clip N) or an ARCTIC sequence (--arctic ROOT --seq sNN/NAME), one of the "
                "two, and no prompts")
    if args.arctic and not args.seq:
        return "--arctic needs --seq sNN/<object>_<grab|use>_NN (a sequence of ROOT/raw_seqs)"
    if (args.seq or args.start is not None) and not args.arctic:
        return "--seq and --start read an ARCTIC sequence: give --arctic ROOT"
    if args.arctic and args.clip is not None:
        return "--clip picks a corpus clip; an ARCTIC sequence's window is picked with --start"
    if args.start is not None and args.start < 0:
        return f"--start must be >= 0, got {args.start}"
    return None


def _object2motion(args, run, opts, t0) -> int:
    """``--task object2motion``: from a hand-object corpus (``--data``, its ``--split``/``--limit`` or ``--clip``) or
    an ARCTIC sequence (``--arctic ROOT --seq sNN/NAME``: consecutive windows of the model's frames, ``--start`` for
    one, ``--limit`` at most that many)."""
    import numpy as np

    from handx_jax.evaluation import object_clips

    G = args.samples
    try:
        if args.arctic:
            out = run.generate_arctic(args.arctic, args.seq, opts, samples=G, start=args.start, limit=args.limit)
            clips, source = np.asarray([r["start"] for r in out["records"]]), str(args.arctic)
            F = out["object_state"].shape[1]
            what = (f"{len(clips)} window(s) of {F} frames of ARCTIC {args.seq} starting at frame(s) "
                    f"{', '.join(str(int(c)) for c in clips)}")
        else:
            clips = run.object_clips(args.data, args.split, args.limit, args.clip)
            out = run.generate_objects(args.data, clips, opts, samples=G)
            source, what = str(args.data), f"{len(clips)} object trajectories"
    except ValueError as e:
        return fail(CMD, e)
    object_clips.write(args.out, **out, clips=clips, source=source)
    print(f"wrote {args.out}: {len(clips) * G} motion(s) of {what}, task {args.task}, {run.describe(opts)}, "
          f"{time.perf_counter() - t0:.1f} s")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("generate", help="sample motion from a trained run", add_help=False, allow_abbrev=False,
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-h", "--help", action="store_true", help="show this help (with --run: the family's options too)")
    p.add_argument("--run", help="run folder (required)")
    p.add_argument("--left", action="append", help="left-hand prompt (repeat for --task long); prompts must not "
                                                   "be empty (refused: no model was trained on an empty caption)")
    p.add_argument("--right", action="append", help="right-hand prompt")
    p.add_argument("--interaction", action="append", help="interaction prompt")
    p.add_argument("--task", default="text2motion",
                   help="text2motion (default), inbetween, keyframes, wrist, reaction, long, prediction; as the "
                        "family supports")
    p.add_argument("--source", help="constraint clip: official-layout .npz or a dataset directory (with --clip)")
    p.add_argument("--clip", help="key in the .npz, or clip id/index in the dataset")
    p.add_argument("--level", type=int, default=-1, help="caption level of prompts taken from data (-1 = most detailed)")
    p.add_argument("--keyframes", help="comma-separated keyframe indices for --task keyframes (default 30)")
    p.add_argument("--fixed-hand", default="left", choices=["left", "right"], help="constrained hand for reaction")
    deprecated_flag(p, "--reference", p.add_argument(
        "--data", metavar="DIR", help="batch mode: dataset directory; one prompt per clip of --split"))
    p.add_argument("--arctic", metavar="ROOT", help="--task object2motion: an ARCTIC release's data folder "
                   "(raw_seqs/, meta/object_vtemplates/); with --seq")
    p.add_argument("--seq", metavar="sNN/NAME", help="--task object2motion: the ARCTIC sequence, e.g. s01/box_use_01; "
                   "generated over its consecutive windows of the model's frames from frame 0 (the frames after the "
                   "last whole window are left out), at most --limit of them")
    p.add_argument("--start", type=int,
                   help="--task object2motion with --arctic: the one window starting at this frame")
    p.add_argument("--split", default="test", choices=["train", "val", "test"])
    p.add_argument("--limit", type=int, help="batch mode: at most N clips (shuffled with seed 42, then sorted)")
    p.add_argument("--samples", type=int, default=1, help="samples per prompt (G)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch-size", type=int, default=256, help="samples per compiled sampler call")
    p.add_argument("--no-ema", action="store_true", help="use the raw (not EMA) parameters")
    p.add_argument("--encoder", help="encoder folder (default: the one the run was trained with)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override the run's generation settings, any family: sample.* (diffusion: sample.sampler, "
                        "sample.steps, sample.contact, sample.contact_strength, sample.contact_schedule; ar: "
                        "sample.temperature, sample.top_k, sample.top_p) and the keys the family "
                        "allows (diffusion.*: guidance, masks); the family's flags below name the same keys")
    p.add_argument("--out", help="output .npz (official layout; required)")
    p.add_argument("--gif", help="also render the first sample as a GIF")
    p.set_defaults(func=_run, parser=p, takes_extra_args=True)
    return p
