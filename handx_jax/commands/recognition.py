"""Caption retrieval from motion (issue 41 item 4): ``handx eval recognition``.

G-HTT recognises an action by the label closest to μ^A (§3.2); HandX has captions, not labels, so
recognition here is "which caption fits this motion": for each clip of a split, its motion's embedding
(``run.embed_motions``) against its own caption's and the other clips' (``run.embed_texts``), scored by the
R-Precision the evaluator uses (``metrics.replicate_embedding_metrics``: top-1/2/3 over blocks of 32 clips,
re-blocked ``--replications`` times, 95% half-widths). Beside it, the standard evaluator's own retrieval of
the same clips' ground-truth motion against the same captions (its "Ground Truth" row), with the same
blocks: the yardstick's ceiling on this split. Any family whose registry entry serves ``recognition`` is
scored (``families.Family.tasks``); the captions are at the evaluator's level (0) unless ``--level``.

Written to ``RUN/eval_recognition.json`` (``--out`` elsewhere).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

CMD = "handx eval recognition"
RESULT_FILE = "eval_recognition.json"
KEYS = ("rprec_top1", "rprec_top2", "rprec_top3")


def _run(args: argparse.Namespace) -> int:
    from handx_jax.commands import fail

    try:
        return _recognize(args)
    except ValueError as e:  # DataError too: a bad run, dataset or option is one line
        return fail(CMD, e)


def _recognize(args: argparse.Namespace) -> int:
    import numpy as np

    from handx_jax.dataset.format import Dataset
    from handx_jax.families import check_task, family_of, load_run
    from handx_jax.generation import check_level, check_limit, split_prompts
    from handx_jax.infra.atomic import atomic_write_json
    from handx_jax.metrics import MetricConfig, replicate_embedding_metrics
    from handx_jax.standard.naming import resolve_evaluator

    if args.block < 2 or args.replications < 1:
        raise ValueError(f"--block must be at least 2 and --replications at least 1, got {args.block}, {args.replications}")
    check_limit(args.limit)
    name = family_of(args.run)
    check_task(name, "recognition")
    from handx_jax.evaluation.prediction import run_data

    named = resolve_evaluator(args.evaluator)  # a bad name or folder: one line, before anything is read
    data = args.data or run_data(args.run)
    ds = Dataset.open(data)
    if args.level is not None:  # the flag first, as eval prediction does; the dataset says which levels exist
        check_level(args.level, int(ds.meta["levels"]), ds.root)
    named.check_data(ds)  # the pairs every command refuses (a corpus-v3 prefix under v7, ...)
    ev = named.load()
    level = ev.policy.eval_level if args.level is None else args.level
    ev.policy = dataclasses.replace(ev.policy, eval_level=level)
    clips, prompts, motions = split_prompts(ds, args.split, args.limit, level)
    if len(clips) < 2:
        raise ValueError(f"the {args.split} split of {data} holds {len(clips)} clip(s); retrieval needs at least 2")
    run = load_run(args.run)
    motion = np.stack(motions)
    cfg = MetricConfig(rprec_block=args.block, replications=args.replications, seed=args.seed)
    em, et = run.embed_motions(motion), run.embed_texts(prompts)
    ours = replicate_embedding_metrics(et, em[None], em, cfg)
    gt = ev.embed_motion(motion)
    L, R, I = ev.captions(ds, clips)
    ref = replicate_embedding_metrics(ev.embed_text(L, R, I), gt[None], gt, cfg)
    block = min(args.block, len(clips))
    res = {"run": {k: {"mean": float(ours[k][0]), "ci": float(ours[k][1])} for k in KEYS},
           "evaluator_ground_truth": {k: {"mean": float(ref[k][0]), "ci": float(ref[k][1])} for k in KEYS},
           "_meta": {"run": str(Path(args.run).absolute()), "family": name, "step": int(run.step),
                     "data": str(Path(data).absolute()), "split": args.split, "clips": len(clips), "level": level,
                     "rprec_block": block, "chance_top1": 1 / block, "chance_top3": 3 / block,
                     "replications": args.replications, "seed": args.seed,
                     "evaluator": str(args.evaluator)}}
    out = Path(args.out) if args.out else Path(args.run) / RESULT_FILE
    atomic_write_json(out, res)
    if args.json:
        json.dump(res, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print(f"{args.run}: {len(clips)} {args.split} clips, captions at level {level}, R-Precision block {block} "
          f"(chance top-1 {1 / block:.3f}, top-3 {3 / block:.3f}), {args.replications} re-blockings")
    for who, r in (("run (motion → caption)", res["run"]), ("standard evaluator, GT", res["evaluator_ground_truth"])):
        print(f"  {who:<26} " + "  ".join(f"{k[6:]} {r[k]['mean']:.3f} ± {r[k]['ci']:.3f}" for k in KEYS))
    print(f"wrote {out}")
    return 0


def add_parser(subparsers) -> None:
    """Add ``recognition`` to the ``handx eval`` group (``handx_jax.cli`` calls this after the group is built)."""
    group = subparsers.choices["eval"]
    sub = next(a for a in group._actions if isinstance(a, argparse._SubParsersAction))
    q = sub.add_parser("recognition", help="caption retrieval from motion (G-HTT recognition), beside the "
                                           "standard evaluator's", description=__doc__.split("\n\n")[0])
    q.add_argument("--run", required=True, help="run folder of a family that serves recognition")
    q.add_argument("--data", help="dataset directory (default: the one the run was trained on)")
    q.add_argument("--split", default="test", choices=["train", "val", "test"])
    q.add_argument("--limit", type=int, metavar="M", help="at most M clips (shuffled with seed 42, then sorted)")
    q.add_argument("--level", type=int, help="caption level (default: the evaluator's, 0)")
    q.add_argument("--block", type=int, default=32, help="R-Precision block (default 32)")
    q.add_argument("--replications", type=int, default=20, help="re-blockings of the clips (default 20)")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--evaluator", default="standard", help="evaluator of the reference row: 'standard' (default), a version "
                                                          "such as standard-v7, or an evaluator folder")
    q.add_argument("--out", help=f"result JSON (default: RUN/{RESULT_FILE})")
    q.add_argument("--json", action="store_true", help="print the result as JSON")
    q.set_defaults(func=_run)
