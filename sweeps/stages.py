"""A run's stages (train → generate → evaluate) and the shared steps it needs, each a ``handx``
subprocess, and the state on disk that says which are done: run and step folders, stale scores
(another evaluator or block), provenance, locks. ``run_one`` brings one run through them.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Sequence

from handx_jax.infra.atomic import atomic_write_json
from handx_jax.infra.errors import DataError
from handx_jax.infra.provenance import versions
from handx_jax.infra.runlock import RunLock, RunLocked, pdeathsig_preexec
from sweeps.spec import REPO, RunSpec, Step, SweepConfig, check_name

def run_dir(cfg: SweepConfig, spec: RunSpec) -> Path:
    out = Path(cfg.out).absolute()
    d = out / "runs" / check_name(spec.name)
    if d.resolve().parent != (out / "runs").resolve():  # e.g. a symlinked runs/NAME pointing elsewhere
        raise DataError(f"run folder {d} resolves outside {out / 'runs'}")
    return d


def step_dir(cfg: SweepConfig, step: Step) -> Path:
    return Path(cfg.out).absolute() / "steps" / step.key


def stage_state(cfg: SweepConfig, spec: RunSpec) -> dict[str, bool]:
    """Which stages are done. Scores are done only if the sweep's evaluator made them: an ``eval.json``
    from another evaluator (a retrained one, a new standard version) is stale, and so are samples
    prompted at another caption level than the evaluator scores (:func:`stale_scores`)."""
    d = run_dir(cfg, spec)
    stale = stale_scores(cfg, d)
    state = {"train": (d / "train_done.json").exists(),
             "generate": (d / "generated.npz").exists() and stale != "generate",
             "evaluate": (d / "eval.json").exists() and stale is None}
    if _predicts(spec):  # scored by the prediction benchmark as well (Family.sweep_task)
        state["predict"] = (d / PREDICTION_FILE).exists()
    if _objects(spec):  # scored by BimArt's metrics, not the text evaluator
        state = {"train": state["train"], "generate": (d / OBJECT_GENERATED).exists(),
                 "evaluate": (d / OBJECT_SCORES).exists()}
    return state


PREDICTION_FILE = "eval_prediction.json"  # evaluation.prediction.RESULT_FILE (not imported: it pulls in JAX)


OBJECT_GENERATED, OBJECT_SCORES = "generated_objects.npz", "eval_objects.json"


def _objects(spec: RunSpec) -> bool:
    return bool(spec.family) and _sweep_task(spec.family) == "object2motion"


def _predicts(spec: RunSpec) -> bool:
    return bool(spec.family) and _sweep_task(spec.family) == "prediction"


def _sweep_task(family: str) -> str:
    from handx_jax.families import entry

    try:
        return entry(family).sweep_task
    except ValueError:  # an unregistered family: launch() names it
        return "text2motion"


@functools.lru_cache(maxsize=8)
def _evaluator_identity(path: str, stamp: tuple) -> tuple[str, int]:
    from handx_jax.evaluation.checkpoint import META_FILE, evaluator_id

    return evaluator_id(path), evaluator_level(Path(path) / META_FILE)


def evaluator_level(meta_path: Path) -> int:
    """The caption level an evaluator scores (its ``evaluator.json``'s ``text.eval_level``)."""
    from handx_jax.infra.readers import get_field, read_json

    return get_field(read_json(meta_path, expect=dict), "text.eval_level", int, path=meta_path)


def evaluator_identity(evaluator: str | os.PathLike) -> tuple[str, int]:
    """(evaluator_id, caption level it scores) of an evaluator folder; cached until its files change."""
    p = Path(evaluator)
    if not p.is_dir():
        raise DataError("no evaluator folder here", path=p)
    stamp = tuple((f.name, f.stat().st_mtime_ns, f.stat().st_size) for f in sorted(p.iterdir()) if f.is_file())
    return _evaluator_identity(str(p.resolve()), stamp)


def _generated_level(d: Path) -> int | None:
    argv = read_json_or_empty(d / "provenance.json").get("stages", {}).get("generate", {}).get("argv") or []
    return int(argv[argv.index("--level") + 1]) if "--level" in argv[:-1] else None


def scored_block(eval_json: Path) -> int:
    """The R-Precision block a scores file (``RUN/eval.json``) was made at (32, the default, where unrecorded)."""
    return int(read_json_or_empty(eval_json).get("_meta", {}).get("rprec_block") or 32)


def scored_at_another_block(eval_json: Path, block: int) -> bool:
    """Whether scores were made at another R-Precision block than scoring them at ``block`` now would use.
    ``handx eval run`` uses one block of all the prompts where there are fewer than asked
    (``evaluation.scoring.rprec_block_used``) and records how many prompts it scored: 16 prompts asked at
    block 32 were scored at block 16, which is what asking for 32 again gives, so they are not redone (every
    relaunch of a sweep with ``--eval-limit 16`` rescored every run)."""
    meta = read_json_or_empty(eval_json).get("_meta", {})
    used, prompts = int(meta.get("rprec_block") or 32), meta.get("prompts")
    if isinstance(prompts, int) and not isinstance(prompts, bool) and prompts > 0:
        return used != min(block, prompts)
    return used != block


def _keep_old_scores(d: Path, block: int) -> Path:
    """Move ``d/eval.json`` aside before a rescore: ``eval.<evaluator id>.json``, with ``.b<block>`` when
    it was scored at another R-Precision block than ``block``; never over an earlier kept file."""
    stem = f"eval.{read_json_or_empty(d / 'eval.json').get('_meta', {}).get('evaluator_id') or 'unrecorded'}"
    old_block = scored_block(d / "eval.json")
    if old_block != block:
        stem += f".b{old_block}"
    keep, k = d / f"{stem}.json", 1
    while keep.exists():
        k += 1
        keep = d / f"{stem}.{k}.json"
    os.replace(d / "eval.json", keep)
    return keep


def stale_scores(cfg: SweepConfig, d: Path) -> str | None:
    """Why a run's scores cannot stand for the sweep's evaluator: ``"generate"`` (its samples were
    prompted at another caption level: regenerate, then rescore), ``"evaluate"`` (scored by another
    evaluator, or by one that did not record its id: rescore), ``"block"`` (scored at another R-Precision
    block than the sweep's: rescore the same samples), or None (current, or nothing to check)."""
    if not cfg.evaluator or not ((d / "eval.json").exists() or (d / "generated.npz").exists()):
        return None
    if not Path(cfg.evaluator).is_dir():  # gone since the launch: nothing to compare (its stage would say so)
        return None
    want_id, level = evaluator_identity(cfg.evaluator)
    got = _generated_level(d)
    if (d / "generated.npz").exists() and got is not None and got != level:
        return "generate"
    if (d / "eval.json").exists() and read_json_or_empty(d / "eval.json").get("_meta", {}).get("evaluator_id") != want_id:
        return "evaluate"
    if (d / "eval.json").exists() and scored_at_another_block(d / "eval.json", cfg.rprec_block):
        return "block"
    return None


def is_complete(cfg: SweepConfig, spec: RunSpec) -> bool:
    st = stage_state(cfg, spec)
    if _objects(spec):
        return st["train"] and st["evaluate"]
    return st["train"] and (not cfg.evaluator or (st["evaluate"] and st.get("predict", True)))


def read_json_or_empty(path: Path) -> dict:
    """A sweep's own JSON object (status.json, sweep.json), or {} when absent. A file that is not a JSON
    object (a ``[]``, a damaged file) is a ``DataError`` naming it (``infra.readers``), not an AttributeError later."""
    from handx_jax.infra.readers import read_json

    return read_json(path, expect=dict, default={})


def update_json(path: Path, **kv) -> None:
    atomic_write_json(path, {**read_json_or_empty(path), **kv})


@functools.lru_cache(maxsize=None)
def git_commit() -> str | None:
    try:
        head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "-uno"], capture_output=True,
                               text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return None
    return (head + ("-dirty" if dirty else "")) if head else None


@functools.lru_cache(maxsize=None)
def device_kind() -> str:
    """The accelerator the runs will train on, without starting JAX in this process (that would take
    GPU memory from the children)."""
    if os.environ.get("JAX_PLATFORMS", "").split(",")[0] == "cpu":
        return "cpu"
    smi = shutil.which("nvidia-smi")
    if smi:
        r = subprocess.run([smi, "--query-gpu=name", "--format=csv,noheader"], capture_output=True, text=True)
        if r.returncode == 0 and r.stdout.strip():
            return r.stdout.strip().splitlines()[0]
    r = subprocess.run([sys.executable, "-c", "import jax; print(jax.devices()[0].device_kind)"],
                       capture_output=True, text=True)
    return r.stdout.strip() or "unknown"


def _env(cfg: SweepConfig) -> dict:
    out = Path(cfg.out).absolute()
    return {"WANDB_RUN_GROUP": cfg.name or out.name,
            # One persistent compilation cache for every run of the sweep: the same shapes (a resumed run,
            # the evaluator in every run's eval stage) compile once. JAX caches only compilations over
            # 1 s by default; tiny CPU runs compile faster than that. A cache the user names is kept (shared
            # with their other sweeps and commands: another sweep's evaluate stages, a relaunch into a new
            # --out, compile nothing again); without one, OUT/jax_cache.
            "JAX_COMPILATION_CACHE_DIR": os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(out / "jax_cache"),
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": os.environ.get("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS",
                                                                         "0.2"),
            "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p)}


def _subst(argv: Sequence[str], mapping: dict) -> list[str]:
    out = []
    for a in argv:
        for k, v in mapping.items():
            a = a.replace("{" + k + "}", str(v))
        out.append(a)
    if out and out[0] == "handx":
        out = [sys.executable, "-m", "handx_jax", *out[1:]]
    return out


def _tail(path: Path, n: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except FileNotFoundError:
        return ""


def run_command(argv: Sequence[str], log: Path, env: dict) -> float:
    """Run one stage's command with output appended to ``log``; raise with the log's tail on failure.

    The child gets SIGTERM if this process dies (PR_SET_PDEATHSIG), so no trainer outlives its launcher.
    """
    log.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with open(log, "ab") as f:
        f.write(f"\n$ {' '.join(argv)}\n".encode())
        f.flush()
        r = subprocess.run(list(argv), env={**os.environ, **env}, stdout=f, stderr=subprocess.STDOUT,
                           preexec_fn=pdeathsig_preexec(signal.SIGTERM))
    if r.returncode != 0:
        raise RuntimeError(f"exit {r.returncode}: {' '.join(argv)}\n--- {log} (last lines) ---\n{_tail(log)}")
    return time.perf_counter() - t0


def _acquire_waiting(lock: RunLock, what: str) -> None:
    """Take ``lock``, waiting (adopting) while a live process holds it."""
    told = False
    while True:
        try:
            lock.acquire()
            return
        except RunLocked as e:
            if not told:
                print(f"   {what}: {e}; waiting for it", flush=True)
                told = True
            time.sleep(1.0)


def ensure_step(step: Step, cfg: SweepConfig) -> Path:
    """Compute a shared step once (under its own lock); later callers find it done."""
    d = step_dir(cfg, step)
    done = d / "step_done.json"
    if done.exists():
        return d
    lock = RunLock(d)
    _acquire_waiting(lock, f"step {step.key}")
    try:
        if not done.exists():
            mapping = {"out": d, "data": cfg.data, "encoder": cfg.encoder}
            secs = sum(run_command(_subst(c, mapping), d / "step.log", _env(cfg)) for c in step.commands)
            atomic_write_json(done, {"step": step.key, "commands": [list(c) for c in step.commands],
                                     "seconds": secs, "git_commit": git_commit()})
    finally:
        lock.release()
    return d


def _step_of(spec: RunSpec, family: str, steps: dict) -> str:
    """The folder of the run's shared step that trains ``family`` (what the registry says it needs)."""
    found = [st for st in spec.needs if st.family == family]
    if len(found) != 1:
        raise ValueError(f"run {spec.name}: family {spec.family} is trained from a {family} run; give exactly one "
                         f"shared step that trains it (sweeps.launcher.family_step), got {len(found)}")
    return steps[found[0].name]["dir"]


def generate_settings(cfg: SweepConfig, spec: RunSpec) -> list[str]:
    """The ``--set`` overrides of a run's generate stage: the registry's sweep defaults for its family, the
    run's own ``sample.*`` overrides, then the sweep's (``handx sweep run --set``); the last one wins."""
    from handx_jax.families import entry

    own = [o for o in spec.overrides if o.split("=", 1)[0].strip().startswith("sample.")]
    return [*entry(spec.family).sweep_sample, *own, *cfg.sample]


def _task_args(spec: RunSpec) -> list[str]:
    """The generate stage's task: the split's captions (text2motion), or, for a family scored on prediction
    (``Family.sweep_task``), the split's clips continued from their first frames (the completed clips are
    what the evaluator then scores)."""
    if _sweep_task(spec.family) != "prediction":
        return []
    from handx_jax.families import PREDICTION_OBSERVED

    return ["--task", "prediction", "--observed-frames", str(PREDICTION_OBSERVED)]


def run_one(spec: RunSpec, cfg: SweepConfig) -> dict[str, bool]:
    """Bring one run through its stages (each skipped if its output exists), holding the run's lock.

    Raises on failure after recording it in RUN/status.json.
    """
    d = run_dir(cfg, spec)
    lock = RunLock(d)
    _acquire_waiting(lock, f"run {spec.name}")
    status = d / "status.json"
    try:
        if is_complete(cfg, spec):
            update_json(status, status="done", error=None)
            return stage_state(cfg, spec)
        update_json(status, status="running", error=None, host=socket.gethostname(), pid=os.getpid(),
                     slurm_job=os.environ.get("SLURM_JOB_ID"))
        prov_path = d / "provenance.json"
        prov = read_json_or_empty(prov_path)
        prov.update(spec=dataclasses.asdict(spec), sweep=cfg.name or Path(cfg.out).name)
        if not (d / "train_done.json").exists() or "git_commit" not in prov:
            # The table's git_commit and device_kind say what *trained* the run: a later rescore or
            # regeneration records its own commit under stages/NAME instead of overwriting them.
            prov.update(git_commit=git_commit(), device_kind=device_kind(), versions=versions())
        prov.setdefault("stages", {})
        env = _env(cfg)
        steps = {}
        for st in spec.needs:
            sd = ensure_step(st, cfg)
            steps[st.name] = {"key": st.key, "dir": str(sd), "commands": [list(c) for c in st.commands]}
        prov["steps"] = steps
        atomic_write_json(prov_path, prov)
        mapping = {"run": d, "data": cfg.data, "encoder": cfg.encoder,
                   **{f"step:{k}": v["dir"] for k, v in steps.items()}}
        state = stage_state(cfg, spec)

        def stage(name: str, argv: list[str]) -> None:
            print(f"   {spec.name}: {name}", flush=True)
            secs = run_command(argv, d / "logs" / f"{name}.log", env)
            prov["stages"][name] = {"seconds": secs, "argv": argv, "finished": time.time(), "git_commit": git_commit(),
                                    "device_kind": device_kind()}
            atomic_write_json(prov_path, prov)

        if not state["train"]:
            if spec.command:
                argv = _subst(spec.command, mapping)
            else:
                from handx_jax.families import entry

                fam = entry(spec.family)
                sets = [a for o in spec.overrides for a in ("--set", _subst([o], mapping)[0])]
                enc = ["--encoder", cfg.encoder] if fam.encoder else []
                needs = [a for n in fam.needs for a in (f"--{n}", _step_of(spec, n, steps))]
                argv = _subst(["handx", "train", spec.family, "--data", cfg.data, *enc, "--preset", spec.preset,
                               *needs, *_subst(spec.args, mapping), *sets, "--out", str(d), "--quiet"], {})
            stage("train", argv)
            atomic_write_json(d / "train_done.json", {"spec": dataclasses.asdict(spec)})
        if _objects(spec):  # the corpus split's objects and trajectories → hands, scored by BimArt's metrics
            if not state["generate"]:
                stage("generate", _subst(["handx", "generate", "--run", str(d), "--task", "object2motion", "--data",
                                          cfg.data, "--split", cfg.eval_split, "--limit", str(cfg.eval_limit),
                                          "--samples", str(cfg.eval_samples),
                                          *(a for o in generate_settings(cfg, spec) for a in ("--set", o)),
                                          "--out", str(d / OBJECT_GENERATED)], {}))
            if not state["evaluate"]:
                stage("evaluate", _subst(["handx", "eval", "objects", "--generated", str(d / OBJECT_GENERATED),
                                          "--json", "--out", str(d / OBJECT_SCORES)], {}))
        elif cfg.evaluator:
            stale = stale_scores(cfg, d)
            if stale and (d / "eval.json").exists():
                # Keep the old yardstick's scores beside the new ones (nothing written is lost).
                keep = _keep_old_scores(d, cfg.rprec_block)
                why = (f"at R-Precision block {scored_block(keep)}, not {cfg.rprec_block}" if stale == "block"
                       else f"by evaluator {read_json_or_empty(keep).get('_meta', {}).get('evaluator_id') or 'unrecorded'}, "
                            f"not {evaluator_identity(cfg.evaluator)[0]}")
                print(f"   {spec.name}: scored {why}: {'regenerating and ' if stale == 'generate' else ''}"
                      f"rescoring (old scores kept in {keep.name})", flush=True)
            if not state["generate"]:
                # Prompt at the caption level the evaluator scores (its text policy), so that the
                # generated file's captions are the ones the evaluator embeds.
                level = evaluator_level(Path(cfg.evaluator) / "evaluator.json")
                stage("generate", _subst(["handx", "generate", "--run", str(d), "--data", cfg.data, "--split",
                                          cfg.eval_split, "--level", str(level), "--limit", str(cfg.eval_limit),
                                          "--samples", str(cfg.eval_samples), *_task_args(spec),
                                          *(a for o in generate_settings(cfg, spec) for a in ("--set", o)),
                                          "--out", str(d / "generated.npz")], {}))
            if not state["evaluate"]:
                stage("evaluate", _subst(["handx", "eval", "run", "--evaluator", cfg.evaluator, "--generated",
                                          str(d / "generated.npz"), "--data", cfg.data, "--block",
                                          str(cfg.rprec_block), "--json", "--out", str(d)], {}))
            if "predict" in state and not state["predict"]:
                from handx_jax.families import PREDICTION_OBSERVED, PREDICTION_SAMPLES

                # The completed clips are scored by the sweep's own evaluator, as the evaluate stage's samples are.
                stage("predict", _subst(["handx", "eval", "prediction", "--run", str(d), "--data", cfg.data,
                                         "--evaluator", cfg.evaluator or "none",
                                         "--split", cfg.eval_split, "--limit", str(cfg.eval_limit), "--samples",
                                         str(PREDICTION_SAMPLES), "--observed-frames", str(PREDICTION_OBSERVED),
                                         *(a for o in generate_settings(cfg, spec) for a in ("--set", o)),
                                         "--json", "--out", str(d / PREDICTION_FILE)], {}))
        update_json(status, status="done", error=None)
        return stage_state(cfg, spec)
    except BaseException as e:
        update_json(status, status="failed", error=f"{type(e).__name__}: {e}"[-4000:])
        raise
    finally:
        lock.release()
