"""``handx sweep``: launch a sweep file locally or on SLURM, check its status, collect its results."""

from __future__ import annotations

import argparse
import json


def _kv(items):
    out = {}
    for it in items or []:
        k, _, v = it.partition("=")
        if not _:
            raise SystemExit(f"handx: error: expected KEY=VALUE, got {it!r}")
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def _run(a: argparse.Namespace) -> int:
    from sweeps.launcher import SweepConfig, launch, load_sweep

    specs = load_sweep(a.sweep, **_kv(a.arg))
    if a.only:
        keep = set(a.only.split(","))
        specs = [s for s in specs if s.name in keep]
    if a.dry_run:
        for s in specs:
            print(json.dumps({"name": s.name, "family": s.family, "preset": s.preset, "overrides": list(s.overrides)}))
        return 0
    cfg = SweepConfig(data=a.data, encoder=a.encoder, out=a.out, evaluator=a.evaluator, eval_limit=a.eval_limit,
                      eval_samples=a.eval_samples, executor=a.executor, slurm=_kv(a.slurm), name=a.name or "")
    print(f"results: {launch(specs, cfg)}")
    return 0


def _status(a: argparse.Namespace) -> int:
    from sweeps.launcher import status

    for row in status(a.out):
        print(f"{row['name']:<24} train {'done' if row['train'] else '-':<5} generate "
              f"{'done' if row['generate'] else '-':<5} evaluate {'done' if row['evaluate'] else '-'}")
    return 0


def _collect(a: argparse.Namespace) -> int:
    from sweeps.launcher import collect_results

    print(collect_results(a.out))
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("sweep", help="launch sweeps (local or SLURM), status, results",
                              description="Run every point of a sweep file through train → generate → evaluate; "
                                          "re-running the same command resumes where it stopped.")
    sub = p.add_subparsers(dest="sweep_command", metavar="SUBCOMMAND")
    sub.required = True
    r = sub.add_parser("run", help="launch (or resume) a sweep")
    r.add_argument("sweep", help="sweep file with runs(**kw), e.g. sweeps/diffusion_scaling.py")
    r.add_argument("--arg", action="append", metavar="KEY=VALUE", help="keyword for runs(), e.g. grid=paper")
    r.add_argument("--data", required=True, help="dataset directory")
    r.add_argument("--encoder", required=True, help="frozen T5 encoder folder")
    r.add_argument("--out", required=True, help="sweep folder (runs/, results.jsonl)")
    r.add_argument("--evaluator", help="evaluator checkpoint; without it runs are trained but not scored")
    r.add_argument("--eval-limit", type=int, default=512, help="test clips generated per run")
    r.add_argument("--eval-samples", type=int, default=1, help="generations per prompt")
    r.add_argument("--executor", choices=("local", "slurm", "debug"), default="local")
    r.add_argument("--slurm", action="append", metavar="KEY=VALUE",
                   help="submitit parameter, e.g. slurm_partition=gpu, timeout_min=600, gpus_per_node=1")
    r.add_argument("--name", help="sweep name (wandb group); default: the --out folder name")
    r.add_argument("--only", help="comma-separated run names")
    r.add_argument("--dry-run", action="store_true", help="print the runs and exit")
    r.set_defaults(func=_run)
    s = sub.add_parser("status", help="which stages of each run are done")
    s.add_argument("out", help="sweep folder")
    s.set_defaults(func=_status)
    c = sub.add_parser("collect", help="rebuild OUT/results.jsonl from the run folders")
    c.add_argument("out", help="sweep folder")
    c.set_defaults(func=_collect)
