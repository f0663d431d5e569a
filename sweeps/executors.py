"""Where runs execute: worker threads on this machine or a SLURM job array (submitit), and the
commands built on them: ``launch``, ``rescore``, ``status``.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from handx_jax.infra.atomic import atomic_write_json
from handx_jax.infra.errors import DataError
from sweeps.spec import RunSpec, SweepConfig
from sweeps.stages import (evaluator_identity, is_complete, read_json_or_empty, run_dir, run_one, stage_state,
                           update_json)
from sweeps.results import collect_quietly, collect_results, load_state, run_status

ACTIVE_SLURM = {"PENDING", "RUNNING", "CONFIGURING", "COMPLETING", "REQUEUED", "REQUEUE_HOLD", "REQUEUE_FED",
                "RESIZING", "SUSPENDED", "SIGNALING", "STAGE_OUT"}


def _submitit():
    """Import submitit without its import-time ``logging.config.dictConfig``: that call closes every
    existing logging handler (e.g. absl's, which JAX installs on sys.stderr), so importing submitit
    in a process that already ran JAX breaks that process's stderr. Its records go to the root logger."""
    if "submitit" not in sys.modules:
        had = "SUBMITIT_LOG_LEVEL" in os.environ
        os.environ.setdefault("SUBMITIT_LOG_LEVEL", "NOCONFIG")
        try:
            import submitit  # noqa: F401
        finally:
            if not had:
                del os.environ["SUBMITIT_LOG_LEVEL"]
    return sys.modules["submitit"]


class _Job:
    """A picklable callable for submitit; requeued jobs simply call run_one again (it resumes)."""

    def __init__(self, spec: RunSpec, cfg: SweepConfig):
        self.spec, self.cfg = spec, cfg

    def __call__(self):
        return run_one(self.spec, self.cfg)

    def checkpoint(self, *args, **kwargs):  # submitit's preemption/timeout hook
        return _submitit().helpers.DelayedSubmission(_Job(self.spec, self.cfg))


@dataclass
class LaunchResult:
    results: Path
    failed: dict[str, str]  # run name -> error

    def __fspath__(self) -> str:
        return str(self.results)

    def read_text(self) -> str:
        return self.results.read_text()


def _local(specs: Sequence[RunSpec], cfg: SweepConfig, out: Path) -> dict[str, str]:
    failed: dict[str, str] = {}

    def one(s: RunSpec) -> None:
        print(f"== {s.name}: {s.family} {s.preset} {' '.join(s.overrides)}", flush=True)
        try:
            run_one(s, cfg)
            print(f"== {s.name}: done", flush=True)
        except Exception as e:
            failed[s.name] = str(e)
            print(f"== {s.name}: FAILED ({str(e).splitlines()[0]})", file=sys.stderr, flush=True)
        collect_quietly(out)

    if cfg.max_parallel <= 1:
        for s in specs:
            one(s)
    else:
        with ThreadPoolExecutor(max_workers=cfg.max_parallel) as pool:
            list(pool.map(one, specs))
    return failed


def squeue_states(job_ids: Sequence[str] | None = None) -> dict[str, str]:
    """{job id: state} of queued/running jobs (array tasks one per line, e.g. ``123_4``)."""
    r = subprocess.run(["squeue", "-h", "-r", "-o", "%i|%T"], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"squeue failed: {r.stderr.strip()}")
    states = dict(ln.split("|", 1) for ln in r.stdout.split() if "|" in ln)
    return states if job_ids is None else {j: states[j] for j in job_ids if j in states}


def sacct_states(job_ids: Sequence[str]) -> dict[str, str]:
    """Final SLURM states (COMPLETED, FAILED, CANCELLED, TIMEOUT, ...) where accounting is available."""
    if not job_ids or not shutil.which("sacct"):
        return {}
    r = subprocess.run(["sacct", "-n", "-X", "-P", "-o", "JobID,State", "-j", ",".join(job_ids)],
                       capture_output=True, text=True)
    out = {}
    for ln in r.stdout.splitlines():
        if "|" in ln:
            j, st = ln.split("|", 1)
            out[j] = st.split()[0] if st else st
    return out


def _slurm(specs: Sequence[RunSpec], cfg: SweepConfig, out: Path) -> dict[str, str]:
    submitit = _submitit()
    params = dict(cfg.slurm)
    jobs_path = out / "slurm_jobs.json"
    old = read_json_or_empty(jobs_path)
    todo = [s for s in specs if not is_complete(cfg, s)]
    active = squeue_states([old[s.name] for s in todo if s.name in old])
    adopted = {s.name: old[s.name] for s in todo if old.get(s.name) in active}
    if adopted and cfg.existing == "cancel":
        print(f"cancelling {len(adopted)} job(s) of an earlier launch: {', '.join(adopted.values())}", flush=True)
        subprocess.run(["scancel", *adopted.values()], check=False)
        deadline = time.time() + 120
        while squeue_states(list(adopted.values())) and time.time() < deadline:
            time.sleep(1.0)
        adopted = {}
    elif adopted:
        print(f"adopting {len(adopted)} job(s) of an earlier launch still queued or running: "
              f"{', '.join(f'{k}={v}' for k, v in adopted.items())}", flush=True)
    submit = [s for s in todo if s.name not in adopted]
    ids = dict(adopted)
    if submit:
        ex = submitit.AutoExecutor(folder=str(out / "submitit"))
        params.setdefault("slurm_array_parallelism", max(cfg.max_parallel, len(submit)))
        ex.update_parameters(name=cfg.name or out.name, **params)
        with ex.batch():  # one job array; each element keeps its checkpoint/requeue hook
            jobs = [ex.submit(_Job(s, cfg)) for s in submit]
        for s, j in zip(submit, jobs):
            ids[s.name] = str(j.job_id)
        print(f"submitted {len(submit)} job(s): {', '.join(f'{s.name}={ids[s.name]}' for s in submit)}", flush=True)
        atomic_write_json(jobs_path, {**read_json_or_empty(jobs_path), **{s.name: ids[s.name] for s in submit}})
    # Wait for every job (not just the first to fail), refreshing the table as runs finish.
    waiting = set(ids.values())
    seen_done: set[str] = set()
    while waiting:
        waiting = set(squeue_states(sorted(waiting)))
        done_now = {s.name for s in todo if is_complete(cfg, s)} - seen_done
        if done_now:
            seen_done |= done_now
            collect_quietly(out)
        if waiting:
            time.sleep(cfg.poll_s)
    unfinished = [s for s in todo if not is_complete(cfg, s)]
    final = sacct_states([ids[s.name] for s in unfinished])
    end = time.time() + 15  # accounting records the final state a few seconds after the job ends
    while unfinished and time.time() < end and any(final.get(ids[s.name], "PENDING") in ACTIVE_SLURM
                                                   for s in unfinished) and shutil.which("sacct"):
        time.sleep(1.0)
        final = sacct_states([ids[s.name] for s in unfinished])
    failed = {}
    for s in unfinished:
        st = read_json_or_empty(run_dir(cfg, s) / "status.json")
        state = final.get(ids[s.name], "unknown (no accounting)")
        err = st.get("error") if st.get("status") == "failed" else None
        failed[s.name] = (f"SLURM job {ids[s.name]} ended in state {state} before the run finished"
                          + (f": {err}" if err else ""))
        update_json(run_dir(cfg, s) / "status.json", status="failed", error=failed[s.name])
    return failed


def launch(specs: Sequence[RunSpec], cfg: SweepConfig) -> LaunchResult:
    """Run every spec (skipping finished stages); return the results table and the runs that failed."""
    out = Path(cfg.out).absolute()
    from handx_jax.families import entry, sweep_task

    for s in specs:
        run_dir(cfg, s)  # refuses names that would leave OUT
    for s in specs:
        try:
            entry(s.family)  # every run names a registered family (its results row says which)
            if cfg.evaluator:  # scored: the family serves the task its sweeps are scored on (Family.sweep_task)
                sweep_task(s.family)
        except ValueError as e:
            raise ValueError(f"run {s.name}: {e}") from None
    if cfg.executor == "slurm" and "timeout_min" not in cfg.slurm:
        raise ValueError("SLURM needs a time limit: give timeout_min in the sweep's RESOURCES for this preset or "
                         "--slurm timeout_min=N (submitit's silent default would end every run after 5 minutes)")
    out.mkdir(parents=True, exist_ok=True)
    prev = read_json_or_empty(out / "sweep.json").get("runs", [])
    names = {s.name for s in specs}
    # Keep the runs of earlier launches (e.g. `--only`) in the table, in their order, then the new ones.
    runs = [r for r in prev if r["name"] not in names] + [dataclasses.asdict(s) for s in specs]
    atomic_write_json(out / "sweep.json", {"config": dataclasses.asdict(cfg), "runs": runs})
    # A relaunch does only what is not done: a finished run (trained, and scored by this evaluator at this
    # block where the sweep scores) is not started again, and a finished sweep says so and does nothing.
    todo = [s for s in specs if not is_complete(cfg, s)]
    if len(todo) < len(specs):
        what = "trained and scored" if cfg.evaluator else "trained"
        print(f"{len(specs) - len(todo)} of {len(specs)} run(s) already {what}: "
              + (f"running the other {len(todo)}" if todo else "nothing to do"), flush=True)
    if cfg.executor == "local":
        failed = _local(todo, cfg, out)
    elif cfg.executor == "slurm":
        failed = _slurm(specs, cfg, out)
    elif cfg.executor == "debug":
        ex = _submitit().AutoExecutor(folder=str(out / "submitit"), cluster="debug")
        failed = {}
        for s in todo:
            try:
                ex.submit(_Job(s, cfg)).result()
            except Exception as e:
                failed[s.name] = str(e)
    else:
        raise ValueError(f"unknown executor {cfg.executor!r} (local | slurm | debug)")
    return LaunchResult(collect_results(out), failed)


def rescore(out: str | os.PathLike, evaluator: str | os.PathLike, *, data: str | os.PathLike | None = None,
            executor: str = "local", max_parallel: int | None = None, rprec_block: int | None = None,
            log=print) -> LaunchResult:
    """Score the trained runs of the sweep in ``out`` with ``evaluator`` (e.g. a new standard version):
    the sweep's own settings (sweep.json: data, samples per prompt, sampler), its runs as launched, only
    the stages that evaluator's scores need (:func:`stale_scores`); nothing is trained. Runs that have
    not finished training are left as they are and named. ``data``: the dataset, if it moved;
    ``rprec_block``: score at this R-Precision block instead of the sweep's (it becomes the sweep's)."""
    out = Path(out).absolute()
    if not out.is_dir():
        raise FileNotFoundError(f"no sweep folder {out}")
    cfg, specs = load_state(out)
    cfg = dataclasses.replace(cfg, out=str(out), evaluator=str(Path(evaluator).absolute()), executor=executor,
                              data=str(Path(data).absolute()) if data else cfg.data,
                              max_parallel=max_parallel or cfg.max_parallel,
                              rprec_block=int(rprec_block or cfg.rprec_block))
    if not Path(cfg.data).is_dir():
        raise DataError(f"the sweep's dataset {cfg.data} is gone; pass the dataset it was run on (--data)",
                        path=out / "sweep.json")
    trained = [s for s in specs if stage_state(cfg, s)["train"]]
    untrained = [s.name for s in specs if s not in trained]
    todo = [s for s in trained if not is_complete(cfg, s)]
    eid = evaluator_identity(cfg.evaluator)[0]
    log(f"rescoring {len(todo)} of {len(specs)} run(s) with evaluator {eid} ({cfg.evaluator}) at R-Precision "
        f"block {cfg.rprec_block}; "
        f"{len(trained) - len(todo)} already scored by it"
        + (f"; not trained, left alone: {', '.join(untrained)}" if untrained else ""))
    if executor == "slurm" and "timeout_min" not in cfg.slurm:
        raise ValueError("SLURM needs a time limit (the sweep was not launched on SLURM): use --executor local")
    res = launch(trained, cfg)
    doc = read_json_or_empty(out / "sweep.json")  # launch put the relaunched runs last: restore the sweep's order
    order = {s.name: i for i, s in enumerate(specs)}
    doc["runs"].sort(key=lambda r: order.get(r["name"], len(order)))
    atomic_write_json(out / "sweep.json", doc)
    return LaunchResult(collect_results(out), res.failed)


def status(out: str | os.PathLike) -> list[dict]:
    """Per run: name, stages done, and done | running | failed | pending."""
    out = Path(out)
    if not out.is_dir():
        raise FileNotFoundError(f"no sweep folder {out}")
    cfg, specs = load_state(out)
    active = None
    if (out / "slurm_jobs.json").exists() and shutil.which("squeue"):
        try:
            active = squeue_states()
        except RuntimeError:
            active = None
    rows = []
    for spec in specs:
        st, err = run_status(out, cfg, spec, active)
        rows.append({"name": spec.name, **stage_state(cfg, spec), "status": st, "error": err})
    return rows
