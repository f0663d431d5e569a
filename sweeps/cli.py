"""``handx sweep``: launch a sweep file locally or on SLURM, check its status, collect its results."""

from __future__ import annotations

import argparse
import inspect
import json
import sys

from handx_jax.cliargs import deprecated_flag, deprecated_positional


def _kv(items):
    out = {}
    for it in items or []:
        k, _, v = it.partition("=")
        if not _:
            raise ValueError(f"expected KEY=VALUE, got {it!r}")
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def _block(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        v = 0
    if v < 2:
        raise argparse.ArgumentTypeError(f"expected a whole number of at least 2, got {text!r}")
    return v


def _sweep_kwargs(a: argparse.Namespace) -> dict:
    from sweeps.spec import _import

    kw = _kv(a.arg)
    params = inspect.signature(_import(a.sweep).runs).parameters
    if a.preset is not None:
        if "preset" not in params:
            raise ValueError(f"{a.sweep} has no presets (its runs() takes no 'preset')")
        kw["preset"] = a.preset
    return kw


RUN = "handx sweep run"


def _fail(command: str, message: object) -> int:
    """``handx sweep COMMAND: error: MESSAGE`` on stderr; exit status 2 (bad input, as every command)."""
    print(f"{command}: error: {message}", file=sys.stderr)
    return 2


def _bad_counts(a: argparse.Namespace) -> str | None:
    """What is wrong with the numbers of ``sweep run`` (checked before the sweep file is run or a folder made)."""
    from handx_jax.infra.values import problem

    for flag, value in (("--eval-limit", a.eval_limit), ("--eval-samples", a.eval_samples),
                        ("--max-parallel", a.max_parallel)):
        wrong = problem(value, whole=True, minimum=1)
        if wrong:
            return f"{flag} {wrong}"
    return None


def _run(a: argparse.Namespace) -> int:
    from pathlib import Path

    from handx_jax.infra.errors import DataError
    from sweeps.launcher import SweepConfig, launch, load_resources, load_rprec_block, load_sweep

    bad = _bad_counts(a) or _bad_sets(a.set)
    if bad:
        return _fail(RUN, bad)
    try:  # the sweep file is user code: every way it can fail is one line naming it (launcher.load_sweep)
        kw = _sweep_kwargs(a)
        specs = load_sweep(a.sweep, **kw)
        preset = kw.get("preset", "")
        resources = {**load_resources(a.sweep, preset), **_kv(a.slurm)}
        block = a.rprec_block or load_rprec_block(a.sweep)
        named = _evaluator(a.evaluator) if a.evaluator else None  # a bad name or folder, even with --dry-run
    except (DataError, FileNotFoundError, ValueError) as e:
        return _fail(RUN, e)
    if a.only:
        keep = set(a.only.split(","))
        unknown = keep - {s.name for s in specs}
        if unknown:
            return _fail(RUN, f"--only names runs the sweep does not have: {', '.join(sorted(unknown))}")
        specs = [s for s in specs if s.name in keep]
    if a.dry_run:
        for s in specs:
            print(json.dumps({"name": s.name, "family": s.family, "preset": s.preset, "axes": s.axes,
                              "overrides": list(s.overrides), "needs": [st.key for st in s.needs]}))
        print(json.dumps({"rprec_block": block}))
        if a.executor == "slurm":
            print(json.dumps({"slurm": resources}))
        return 0
    from handx_jax.families import entry

    def needs_encoder(s) -> bool:  # the run, or a step it needs, trains a family that reads the text encoder
        return (bool(s.family) and not s.command and entry(s.family).encoder) or any(
            st.family and entry(st.family).encoder for st in s.needs)

    if not a.data or (not a.encoder and any(needs_encoder(s) for s in specs)):
        fams = sorted({s.family for s in specs if needs_encoder(s)})
        return _fail(RUN, f"--data (and --encoder for {', '.join(fams) or 'these'} runs) are required")
    if named is not None:  # the evaluator's pair with the data, before the first run trains (issue 54 item 2)
        from handx_jax.dataset.format import Dataset

        try:
            named.check_data(Dataset.open(a.data))
        except (DataError, FileNotFoundError, ValueError) as e:
            return _fail(RUN, e)
    cfg = SweepConfig(data=str(Path(a.data).absolute()), encoder=str(Path(a.encoder).absolute()) if a.encoder else "",
                      out=a.out, evaluator=str(named.folder.absolute()) if named else None,
                      eval_limit=a.eval_limit, eval_samples=a.eval_samples, rprec_block=block, sample=tuple(a.set),
                      executor=a.executor, slurm=resources,
                      name=a.name or "", preset=preset, max_parallel=a.max_parallel, existing=a.existing)
    return _launched("run", lambda: launch(specs, cfg), len(specs))


def _evaluator(value: str | None, data: str | None = None):
    """The evaluator (``standard``, ``standard-vN`` or a path, resolved by ``standard.naming``), checked
    against the sweep's dataset when it is given; the stages are passed its folder."""
    from handx_jax.dataset.format import Dataset
    from handx_jax.standard.naming import resolve_evaluator

    named = resolve_evaluator(value)
    if data is not None:
        named.check_data(Dataset.open(data))
    return named


def _bad_sets(sets) -> str | None:
    bad = [o for o in sets if not o.split("=", 1)[0].strip().startswith("sample.") or "=" not in o]
    if bad:
        return f"--set takes the runs' generation settings, sample.KEY=VALUE; got {', '.join(map(repr, bad))}"
    return None


def _launched(command: str, go, total: int | None = None) -> int:
    """Run a launch (``go()``), print where its results are and each failure; the exit status."""
    from handx_jax.infra.errors import DataError

    try:
        res = go()
    except (DataError, FileNotFoundError, ValueError) as e:
        print(f"handx sweep {command}: error: {e}", file=sys.stderr)
        return 2
    print(f"results: {res.results} (and {res.results.with_suffix('.csv')})")
    if res.failed:
        for name, err in res.failed.items():
            print(f"FAILED {name}: {err.splitlines()[0] if err else ''}", file=sys.stderr)
        of = f" of {total}" if total is not None else ""
        print(f"handx sweep {command}: {len(res.failed)}{of} run(s) failed (see their logs/ and status.json)",
              file=sys.stderr)
        return 1
    return 0


def _status(a: argparse.Namespace) -> int:
    from handx_jax.infra.errors import DataError
    from sweeps.launcher import status

    try:
        rows = status(a.out)
    except (DataError, FileNotFoundError) as e:
        print(f"handx sweep status: error: {e}", file=sys.stderr)
        return 2
    if a.json:
        for r in rows:
            print(json.dumps(r))
        return 0
    for r in rows:
        stages = " ".join(f"{k} {'done' if r[k] else '-':<4}" for k in ("train", "generate", "evaluate"))
        err = f"  {r['error'].splitlines()[0][:100]}" if r.get("error") else ""
        print(f"{r['name']:<28} {r['status']:<8} {stages}{err}")
    counts = {k: sum(r["status"] == k for r in rows) for k in ("done", "running", "failed", "pending")}
    print(", ".join(f"{v} {k}" for k, v in counts.items()))
    return 0


def _rescore(a: argparse.Namespace) -> int:
    from handx_jax.infra.errors import DataError
    from sweeps.launcher import rescore

    try:
        ev = str(_evaluator(a.evaluator, a.data).folder.absolute())
    except (DataError, FileNotFoundError, ValueError) as e:
        print(f"handx sweep rescore: error: {e}", file=sys.stderr)
        return 2
    return _launched("rescore", lambda: rescore(a.out, ev, data=a.data, executor=a.executor,
                                                max_parallel=a.max_parallel, rprec_block=a.rprec_block))


def _collect(a: argparse.Namespace) -> int:
    from sweeps.launcher import collect_results

    print(collect_results(a.out))
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("sweep", help="launch sweeps (local or SLURM), status, results",
                              description="Run every point of a sweep file through its shared steps and "
                                          "train → generate → evaluate; re-running the same command resumes "
                                          "where it stopped.")
    sub = p.add_subparsers(dest="sweep_command", metavar="SUBCOMMAND")
    sub.required = True
    r = sub.add_parser("run", help="launch (or resume) a sweep",
                       description="Launch (or resume) a sweep. A run that fails is recorded and the others go "
                                   "on; the exit status is 1 if any failed. Results: OUT/results.jsonl and "
                                   "OUT/results.csv.")
    r.add_argument("sweep", help="sweep file with runs(preset=..., **kw), e.g. sweeps/diffusion_depth_data.py")
    r.add_argument("--preset", help="the sweep's preset: tiny (CPU) or paper (the paper's sizes)")
    r.add_argument("--arg", action="append", metavar="KEY=VALUE", help="other keyword for runs(), e.g. steps=500")
    r.add_argument("--data", help="dataset directory")
    r.add_argument("--encoder", help="frozen T5 encoder folder")
    r.add_argument("--out", required=True, help="sweep folder (runs/, steps/, results.jsonl, results.csv)")
    r.add_argument("--evaluator", help="'standard' (the packaged one), a version such as standard-v6, or an evaluator "
                                       "folder; checked against --data before any run trains. Without it runs are "
                                       "trained but not scored")
    r.add_argument("--eval-limit", type=int, default=512, help="test clips generated per run")
    r.add_argument("--eval-samples", type=int, default=1, help="generations per prompt")
    deprecated_flag(r, "--rprec-block", r.add_argument(
        "--block", type=_block, default=None, dest="rprec_block",
        help="R-Precision block of the evaluate stage (default: the sweep file's RPREC_BLOCK, else 32; "
                        "the flops ladder's is 16, as the paper's Table B / Fig. 4)"))
    r.add_argument("--set", action="append", default=[], metavar="sample.KEY=VALUE",
                   help="generation setting of every run's generate stage (over the family's sweep default and the "
                        "run's own sample.* overrides), e.g. sample.steps=25 (diffusion: sample.sampler, "
                        "sample.steps; ar: sample.temperature, sample.top_k, sample.top_p)")
    r.add_argument("--executor", choices=("local", "slurm", "debug"), default="local")
    r.add_argument("--max-parallel", type=int, default=1,
                   help="runs at once (local: worker threads; SLURM: the array's parallelism)")
    r.add_argument("--slurm", action="append", metavar="KEY=VALUE",
                   help="submitit parameter over the preset's RESOURCES, e.g. slurm_partition=gpu, timeout_min=600")
    r.add_argument("--existing", choices=("adopt", "cancel"), default="adopt",
                   help="SLURM jobs of an earlier launch of this sweep that still run: wait for them (adopt, "
                        "default) or cancel and resubmit them")
    r.add_argument("--name", help="sweep name (wandb group); default: the --out folder name")
    r.add_argument("--only", help="comma-separated run names")
    r.add_argument("--dry-run", action="store_true", help="print the runs (and SLURM resources) and exit")
    r.set_defaults(func=_run)
    s = sub.add_parser("status", help="done, running, failed and pending runs")
    deprecated_positional(s, s.add_argument("--out", required=True, metavar="OUT", help="sweep folder"), "out")
    s.add_argument("--json", action="store_true", help="one JSON object per run")
    s.set_defaults(func=_status)
    q = sub.add_parser("rescore", help="score a sweep's trained runs with another evaluator (nothing is retrained)",
                       description="Score every trained run of the sweep in OUT with EVALUATOR (default: the packaged "
                                   "standard evaluator), with the sweep's own generation settings. Only stale work is "
                                   "done: runs already scored by it are kept, others are rescored from their samples "
                                   "(regenerated first only if EVALUATOR scores another caption level); the old "
                                   "scores stay as RUN/eval.<old id>.json.")
    deprecated_positional(q, q.add_argument("--out", required=True, metavar="OUT", help="sweep folder (must exist)"), "out")
    q.add_argument("--evaluator", help="'standard' (default, the packaged one), a version such as standard-v6, or an "
                                       "evaluator folder")
    q.add_argument("--data", help="the sweep's dataset, if it moved since the launch")
    q.add_argument("--executor", choices=("local", "slurm", "debug"), default="local")
    q.add_argument("--max-parallel", type=int, default=None, help="runs scored at once (default: the sweep's)")
    deprecated_flag(q, "--rprec-block", q.add_argument(
        "--block", type=_block, default=None, dest="rprec_block",
        help="R-Precision block to score at (default: the sweep's); runs scored at another block are "
                        "rescored from their samples, the old scores kept as RUN/eval.<id>.b<block>.json"))
    q.set_defaults(func=_rescore)
    c = sub.add_parser("collect", help="rebuild OUT/results.jsonl and OUT/results.csv from the run folders")
    deprecated_positional(c, c.add_argument("--out", required=True, metavar="OUT", help="sweep folder (must exist)"), "out")
    c.set_defaults(func=_collect)
