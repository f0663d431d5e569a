"""``handx eval …``: train the text–motion evaluator and score generated motion (paper Table 2).

    handx eval train-evaluator --data DIR --encoder ENC --out E [--preset small] [--steps N] [--set key.sub=v]
    handx eval run [--evaluator E] --generated G.npz --reference DIR [--samples K] [--json] [--out RUN_DIR]
    handx eval run --evaluator E --ground-truth --reference DIR [--json]

``--json`` prints one object whose keys are the analysis schema's metric names and ``<name>_ci``
(what the sweep launcher records); ``--out`` also writes it as ``RUN_DIR/eval.json`` (+ ``_meta``).
Besides the paper's Table 2 it reports G-HTT's MPJPE-RA/-PA and APD per hand (APD with two or more
samples per prompt: ``handx generate --samples K``) and BimArt's Pen 1cm, penetration depth and contact
feasibility (handx_jax/metrics.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

from handx_jax.config import add_config_args

def _train(args: argparse.Namespace) -> int:
    from handx_jax.commands import fail
    from handx_jax.config import print_config
    from handx_jax.evaluation import make_evaluator_config, train_evaluator

    # The named flags are shorthands for config keys; --set (applied after them) reaches every key.
    flags = [("train.steps", args.steps), ("train.batch_size", args.batch_size), ("train.optim.lr", args.lr),
             ("train.optim.warmup_steps", args.warmup), ("text.max_len", args.max_len),
             ("text.train_levels", None if args.train_levels is None else
              ("none" if args.train_levels == "all" else args.train_levels)),
             ("text.eval_level", args.eval_level), ("metrics.rprec_block", args.block)]
    sets = [f"{k}={v}" for k, v in flags if v is not None]
    if args.no_final_eval:
        sets.append("final_eval=false")
    try:
        cfg = make_evaluator_config(args.preset, sets + args.set, data=args.data, encoder=args.encoder)
    except ValueError as e:
        return fail("handx eval train-evaluator", e)
    if args.print_config:
        print_config(cfg)
        return 0
    train_evaluator(args.out, cfg, force=args.force)
    return 0


def _run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from handx_jax.data.dataset import Dataset
    from handx_jax.evaluation import (evaluate_generated, evaluate_ground_truth, format_table, load_evaluator,
                                      write_eval_json)
    from handx_jax.metrics import MetricConfig

    if bool(args.generated) == bool(args.ground_truth):
        raise SystemExit("handx: error: give exactly one of --generated G.npz or --ground-truth")
    if args.replications < 1:
        raise SystemExit(f"handx: error: --replications must be at least 1, got {args.replications}")
    if args.samples is not None and args.samples < 2:
        raise SystemExit(f"handx: error: --samples (APD's K) must be at least 2, got {args.samples}")
    cfg = MetricConfig(rprec_block=args.block, replications=args.replications, seed=args.seed,
                       mpjpe_root=args.mpjpe_root, apd_samples=args.samples or 0)
    cache = not args.no_reference_cache
    from handx_jax.io import DataError

    if args.generated:  # read and range-checked before any model is loaded: bad motion fails in a second
        from handx_jax.data.handx_npz import read_handx_npz
        from handx_jax.evaluation.scoring import check_motion_range

        entries = read_handx_npz(args.generated)
        try:
            for e in entries:
                check_motion_range(e.motion, clip=e.key)
        except DataError as e:
            raise DataError(str(e), path=args.generated) from None
    from handx_jax import standard

    if standard.is_standard(args.evaluator):  # the packaged standard evaluator (handx_jax/standard.py)
        if args.encoder:
            raise SystemExit("handx: error: --encoder applies to --evaluator E; the standard evaluator carries its own")
        ev, cache = standard.load(), (standard.reference_cache_dir() if cache else False)
    else:
        ev = load_evaluator(args.evaluator, encoder=args.encoder)
    if args.level is not None:
        ev.policy = dataclasses.replace(ev.policy, eval_level=args.level)
    ds = Dataset.open(args.reference)
    if args.ground_truth:
        res, name = evaluate_ground_truth(ev, ds, cfg, split=args.split, cache=cache), "Ground Truth"
    else:
        try:
            res = evaluate_generated(ev, entries, ds, cfg, split=args.split, cache=cache)
        except DataError as e:  # a clip's error names the file it came from too
            raise e if e.path is not None else DataError(str(e), path=args.generated) from None
        res.meta["generated"] = str(Path(args.generated).absolute())
        name = args.label or Path(args.generated).stem
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        write_eval_json(Path(args.out) / "eval.json", res)
    if args.json:
        json.dump(res.flat(), sys.stdout)
        sys.stdout.write("\n")
    else:
        print(format_table([(name, res)], block=args.block))
        s = res.meta["seconds"]
        print(f"{res.meta['prompts']} prompts × {res.meta['groups']} group(s), {args.replications} replications; "
              f"embedding {s['text_embedding'] + s['motion_embedding']:.2f} s, metrics {s['metrics']:.2f} s")
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("eval", help="evaluator training and Table 2 metrics",
                              description="Train the text–motion evaluator; score generated motion.")
    sub = p.add_subparsers(dest="eval_command", metavar="SUBCOMMAND")
    sub.required = True

    t = sub.add_parser("train-evaluator", help="train a contrastive evaluator; write a versioned checkpoint folder",
                       description="Train the evaluator (config: handx_jax.evaluation.EvaluatorRunConfig; --set takes "
                                   "its dotted keys: model.*, text.*, train.*, train.optim.*, data.text_bucket, "
                                   "metrics.*, final_eval). Re-running resumes an unfinished folder (same config).")
    t.add_argument("--data", required=True, help="dataset directory (trains on its train split)")
    t.add_argument("--encoder", required=True, help="frozen T5 encoder folder (Hugging Face layout)")
    t.add_argument("--out", required=True, help="evaluator folder E (resumed if unfinished)")
    add_config_args(t, ("tiny", "small", "paper"), default="small", example="model.layers=2")
    t.add_argument("--steps", type=int, help="training steps (train.steps; default 3000)")
    t.add_argument("--batch-size", type=int, help="train.batch_size (default 128)")
    t.add_argument("--lr", type=float, help="train.optim.lr (default 3e-4)")
    t.add_argument("--warmup", type=int, help="train.optim.warmup_steps (default 200, capped at steps/5)")
    t.add_argument("--max-len", type=int, help="joined-caption token limit (text.max_len; default 256)")
    t.add_argument("--train-levels", help="comma-separated caption levels to train on, or 'all' (default 0)")
    t.add_argument("--eval-level", type=int, help="caption level used at evaluation (−1 = most detailed; default 0)")
    t.add_argument("--block", type=int, help="R-Precision block of the final Ground Truth row (default 32)")
    t.add_argument("--no-final-eval", action="store_true", help="skip the Ground Truth row on the test split")
    t.add_argument("--force", action="store_true", help="retrain over a finished evaluator folder")
    t.set_defaults(func=_train)

    r = sub.add_parser("run", help="Table 2 metrics of generated motion (or the Ground Truth row)")
    r.add_argument("--evaluator", help="evaluator folder E; default (or 'standard', or the packaged folder): the "
                                       "standard evaluator, which scores the standard corpus and its prefixes "
                                       "(`handx standard info`)")
    r.add_argument("--generated", help="generated clips: HandX .npz (entries may carry source_clip, group)")
    r.add_argument("--ground-truth", action="store_true", help="score the reference split's GT motion itself")
    r.add_argument("--reference", required=True, help="the dataset the evaluator was trained on")
    r.add_argument("--split", default="test", help="reference split (GT row; generated files without source_clip)")
    r.add_argument("--encoder", help="encoder folder, if moved since training (fingerprint-checked)")
    r.add_argument("--level", type=int, help="caption level to score against (default: the evaluator's eval_level; "
                                             "−1 = most detailed)")
    r.add_argument("--no-reference-cache", action="store_true",
                   help="neither read nor write E/reference_cache/ (the reference captions' and GT embeddings)")
    r.add_argument("--replications", type=int, default=20)
    r.add_argument("--block", type=int, default=32, help="R-Precision block size (32: Table 2; 16: Fig. 4)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--mpjpe-root", default="none", choices=["none", "left_wrist", "per_hand_wrist"])
    r.add_argument("--samples", type=int, metavar="K",
                   help="APD over the first K samples (generation groups) of each prompt, as G-HTT's K = 20 "
                        "(default: all groups; the file must hold at least K; APD needs K >= 2)")
    r.add_argument("--label", help="row name in the printed table")
    r.add_argument("--json", action="store_true", help="print {metric: mean, metric_ci: half-width} as JSON")
    r.add_argument("--out", help="run folder: also write RUN_DIR/eval.json")
    r.set_defaults(func=_run)
