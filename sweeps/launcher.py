"""The sweep launcher: every run of a sweep file, locally or on SLURM, resumable, results as a table.

A sweep is a plain Python file with ``runs(preset="tiny", **kw) -> list[RunSpec]`` and, for SLURM,
``RESOURCES = {"tiny": {...}, "paper": {...}}`` (submitit parameters per preset; see
``sweeps/diffusion_depth_data.py``). Each run goes through idempotent stages, each a ``handx``
subprocess so that one run's crash or memory never takes the sweep down:

    steps     shared steps the run needs (e.g. a tokenizer per codebook), in OUT/steps/NAME-HASH/,
              named from a hash of their commands: computed once, found again by every run
    train     handx train FAMILY --preset P --set ... --out RUN       (resumes from RUN/checkpoints)
    generate  handx generate --run RUN --data DATA --split test --limit N --out RUN/generated.npz
    evaluate  handx eval run --evaluator E --generated RUN/generated.npz --data DATA --json --out RUN

A stage is done when its output exists (every output is written atomically), so a killed sweep re-run
with the same command picks up where it stopped; finished runs are not redone. One run's failure is
recorded (RUN/status.json, the table's ``status``/``error``) and the sweep goes on; ``launch`` reports
the failures and the command exits non-zero at the end.

Scores belong to an evaluator. ``eval.json`` records the id of the evaluator that made it
(``handx_jax.evaluation.evaluator_id``: a hash of its weights and config), and a run counts as scored
only if that is the sweep's evaluator. Relaunching a finished sweep with another ``--evaluator`` (a
retrained one, a new version of the packaged standard evaluator) therefore rescores every run without
retraining it, keeps the old scores as ``RUN/eval.<old id>.json``, and regenerates the samples first
only if the new evaluator scores another caption level. Tables carry ``evaluator``/``evaluator_id``,
and ``handx analyze fit`` refuses rows scored by two evaluators.

One writer per run folder: the process bringing a run through its stages holds ``RunLock(RUN)``
(handx_jax/runlock.py), and its children inherit it. A relaunch waits for (adopts) a run whose lock
is held by a live process instead of starting a second trainer beside it; a lock left by a dead
process is recovered. Children are started with PR_SET_PDEATHSIG, so a launcher killed with -9 takes
its training child with it.

SLURM (``executor="slurm"``): one job array per launch, resources and time limit from the sweep's
preset (refused without a time limit: submitit's 5-minute default must not end runs silently). Job ids
go to OUT/slurm_jobs.json; a relaunch adopts (waits for) jobs of an earlier launch that are still
queued or running, or cancels them first with ``existing="cancel"``, instead of duplicating them. The
launcher waits for every job and records each failure (with SLURM's state, e.g. CANCELLED).

Results: after every run, OUT/results.jsonl and OUT/results.csv are rebuilt (atomically) from the run
folders, one row per run of the sweep: axis values, params, FLOPs in both conventions, training
compute, metrics with CIs, wall time, device kind, git commit, status. All runs share a persistent
JAX compilation cache: the user's JAX_COMPILATION_CACHE_DIR if set, else OUT/jax_cache.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib.util
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from handx_jax.io import DataError, atomic_write_json, read_json
from handx_jax.provenance import versions
from handx_jax.runlock import RunLock, RunLocked, is_locked, pdeathsig_preexec

REPO = Path(__file__).resolve().parent.parent
# A run or step name is one path component: no separators, no "..", nothing hidden.
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._=+,-]{0,127}$")
ACTIVE_SLURM = {"PENDING", "RUNNING", "CONFIGURING", "COMPLETING", "REQUEUED", "REQUEUE_HOLD", "REQUEUE_FED",
                "RESIZING", "SUSPENDED", "SIGNALING", "STAGE_OUT"}


def check_name(name: str, what: str = "run") -> str:
    if not isinstance(name, str) or not NAME_RE.match(name) or ".." in name:
        raise DataError(f"{what} name {name!r} is not allowed: use letters, digits and . _ = + , - "
                        f"(no '/', no '..', at most 128 characters), so that it stays inside --out")
    return name


@dataclass(frozen=True)
class Step:
    """A shared step (marin's ExecutorStep): ``commands`` run in order into one folder named from
    their hash, computed once and reused by every run that needs it.

    Placeholders in the commands: ``{out}`` (the step folder), ``{data}``, ``{encoder}``; an argv
    starting with ``handx`` runs this package's CLI.
    """

    name: str
    commands: tuple[tuple[str, ...], ...]
    version: str = "1"
    family: str = ""  # the family whose run the step trains (``family_step``), if any

    @property
    def key(self) -> str:
        doc = json.dumps({"name": self.name, "commands": [list(c) for c in self.commands], "version": self.version},
                         sort_keys=True)
        return f"{self.name}-{hashlib.sha256(doc.encode()).hexdigest()[:12]}"


def family_step(family: str, name: str, preset: str, overrides: Sequence[str] = ()) -> Step:
    """A shared step that trains one run of ``family`` (e.g. the AR LM's tokenizer, keyed by its
    ``model.codebook``) and runs the registry's ``after_train`` commands on it (the token cache)."""
    from handx_jax.families import entry

    fam = entry(family)
    train = ("handx", "train", family, "--data", "{data}", *(("--encoder", "{encoder}") if fam.encoder else ()),
             "--preset", preset, *(a for o in overrides for a in ("--set", o)), "--out", "{out}", "--quiet")
    return Step(name, (train, *fam.after_train), family=family)


def axes_of(overrides: Sequence[str], *names: str) -> dict:
    """A point's axis values read from its own overrides (``model.layers=4`` → ``{"layers": 4}``), so a
    value such as the data fraction is written once, as the override, and the row and the run id follow."""
    keys = {"layers": "model.layers", "dim": "model.dim", "heads": "model.heads", "ff": "model.ff",
            "data_fraction": "data.fraction", "codebook": "model.codebook"}
    given = dict(o.split("=", 1) for o in overrides)
    out = {}
    for n in names:
        v = given[keys.get(n, n)]
        out[n] = float(v) if n == "data_fraction" else int(v)
    return out


@dataclass(frozen=True)
class RunSpec:
    """One point of a sweep: a family, a size preset and dotted config overrides.

    ``axes`` holds the point's axis values (schema columns, e.g. ``{"layers": 4, "data_fraction": 0.05}``;
    ``axes_of`` reads them from the overrides) for the run id and the results row; ``needs`` the shared
    steps it depends on (``{step:NAME}`` in an override is replaced by that step's folder; a step that
    trains a family the registry says this family needs is passed as ``--FAMILY STEP_DIR``); ``args``
    are extra arguments of ``handx train FAMILY``; ``command``, if given, replaces the train stage's argv
    (placeholders ``{run}``, ``{data}``, ``{encoder}``, ``{step:NAME}``). Overrides under ``sample.*``
    are the run's generation settings (its generate stage uses them).
    """

    name: str
    family: str = ""  # a registered family (handx_jax.families); ``launch`` refuses a run without one
    preset: str = "tiny"
    overrides: tuple[str, ...] = ()
    axes: dict = field(default_factory=dict)
    needs: tuple[Step, ...] = ()
    args: tuple[str, ...] = ()
    command: tuple[str, ...] = ()


def run_id(axes: dict, overrides: Sequence[str]) -> str:
    """A deterministic, readable run id: the axis values, then a hash of every override (so two runs
    that differ in any setting never share a folder)."""
    short = {"layers": "L", "dim": "d", "heads": "H", "ff": "ff", "data_fraction": "f", "codebook": "K",
             "lm": "lm", "data_sampling": "s"}
    head = "-".join(f"{short.get(k, k)}{v:g}" if isinstance(v, float) else f"{short.get(k, k)}{v}"
                    for k, v in axes.items())
    h = hashlib.sha256("\n".join(sorted(overrides)).encode()).hexdigest()[:6]
    return check_name(f"{head}-{h}" if head else h)


@dataclass(frozen=True)
class SweepConfig:
    data: str
    encoder: str
    out: str
    evaluator: str | None = None  # without one, runs are trained (and generate) but not scored
    eval_split: str = "test"
    eval_limit: int = 512
    eval_samples: int = 1
    # R-Precision block of the evaluate stage: 32 as in Tables 2-5, 16 for Table B / Fig. 4 (a sweep file's
    # RPREC_BLOCK). Top-k R-Precision at two blocks are two metrics (chance k/block): never one curve.
    rprec_block: int = 32
    # Generation settings of every run's generate stage (``sample.*`` overrides, ``handx sweep run --set``),
    # over the registry's ``sweep_sample`` and each run's own ``sample.*`` overrides.
    sample: tuple[str, ...] = ()
    executor: str = "local"  # local | slurm | debug (submitit's in-process executor, for tests)
    slurm: dict = field(default_factory=dict)  # submitit parameters (the sweep preset's RESOURCES + --slurm)
    name: str = ""
    preset: str = ""
    max_parallel: int = 1
    existing: str = "adopt"  # SLURM jobs of an earlier launch still queued/running: adopt | cancel
    poll_s: float = 3.0


def _import(path: str | os.PathLike):
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no sweep file {path}")
    spec = importlib.util.spec_from_file_location(f"handx_sweep_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise FileNotFoundError(f"cannot import sweep file {path}")
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    except SyntaxError as e:
        raise DataError(f"sweep file has a syntax error at line {e.lineno}: {e.msg}", path=path) from None
    except Exception as e:  # the sweep file is user code: whatever it raises is one line naming it
        raise DataError(f"sweep file failed to import: {_one_line(e)}", path=path) from None
    if not callable(getattr(mod, "runs", None)):
        raise DataError("sweep file defines no runs(**kw) function", path=path)
    return mod


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0][:300]}" if text else type(e).__name__


def load_sweep(path: str | os.PathLike, **kwargs) -> list[RunSpec]:
    """Import a sweep file and call its ``runs(**kwargs)``; what it returns is checked here, before anything
    is launched: a non-empty list of :class:`RunSpec`, names allowed and unique. Every failure is a
    ``DataError`` naming the file."""
    runs = _import(path).runs
    call = f"runs({', '.join(f'{k}={v!r}' for k, v in kwargs.items())})"
    try:
        specs = runs(**kwargs)
    except Exception as e:
        raise DataError(f"{call} raised {_one_line(e)}", path=path) from None
    if not isinstance(specs, (list, tuple)):
        got = "None" if specs is None else f"a {type(specs).__name__}"
        raise DataError(f"{call} returned {got}, not a list of RunSpec (did it forget `return`?)", path=path)
    if not specs:
        raise DataError(f"{call} returned no runs: nothing to launch", path=path)
    for i, s in enumerate(specs):
        if not isinstance(s, RunSpec):
            raise DataError(f"{call} item {i} is a {type(s).__name__}, not a RunSpec", path=path)
    try:
        names = [check_name(s.name) for s in specs]
        for s in specs:
            for st in s.needs:
                check_name(st.name, "step")
    except DataError as e:
        raise DataError(str(e), path=path) from None
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DataError(f"run names must be unique; repeated: {', '.join(dup)}", path=path)
    return list(specs)


def load_rprec_block(path: str | os.PathLike) -> int:
    """The sweep file's R-Precision block (``RPREC_BLOCK``; 32, Tables 2-5, if it names none)."""
    block = getattr(_import(path), "RPREC_BLOCK", 32)
    if not isinstance(block, int) or isinstance(block, bool) or block < 2:
        raise ValueError(f"{path}: RPREC_BLOCK must be a whole number of at least 2, got {block!r}")
    return block


def load_resources(path: str | os.PathLike, preset: str) -> dict:
    """The sweep file's SLURM resources for ``preset`` (``RESOURCES[preset]``), {} if it has none."""
    res = getattr(_import(path), "RESOURCES", {})
    return dict(res.get(preset, {}))


# ------------------------------------------------------------------------------------------------
# Paths, state, provenance


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
    return {"train": (d / "train_done.json").exists(),
            "generate": (d / "generated.npz").exists() and stale != "generate",
            "evaluate": (d / "eval.json").exists() and stale is None}


@functools.lru_cache(maxsize=8)
def _evaluator_identity(path: str, stamp: tuple) -> tuple[str, int]:
    from handx_jax.evaluation.checkpoint import META_FILE, evaluator_id

    return evaluator_id(path), int(json.loads((Path(path) / META_FILE).read_text())["text"]["eval_level"])


def evaluator_identity(evaluator: str | os.PathLike) -> tuple[str, int]:
    """(evaluator_id, caption level it scores) of an evaluator folder; cached until its files change."""
    p = Path(evaluator)
    if not p.is_dir():
        raise DataError("no evaluator folder here", path=p)
    stamp = tuple((f.name, f.stat().st_mtime_ns, f.stat().st_size) for f in sorted(p.iterdir()) if f.is_file())
    return _evaluator_identity(str(p.resolve()), stamp)


def _generated_level(d: Path) -> int | None:
    argv = _read_json(d / "provenance.json").get("stages", {}).get("generate", {}).get("argv") or []
    return int(argv[argv.index("--level") + 1]) if "--level" in argv[:-1] else None


def _scored_block(eval_json: Path) -> int:
    """The R-Precision block a scores file (``RUN/eval.json``) was made at (32, the default, where unrecorded)."""
    return int(_read_json(eval_json).get("_meta", {}).get("rprec_block") or 32)


def _keep_old_scores(d: Path, block: int) -> Path:
    """Move ``d/eval.json`` aside before a rescore: ``eval.<evaluator id>.json``, with ``.b<block>`` when
    it was scored at another R-Precision block than ``block``; never over an earlier kept file."""
    stem = f"eval.{_read_json(d / 'eval.json').get('_meta', {}).get('evaluator_id') or 'unrecorded'}"
    old_block = _scored_block(d / "eval.json")
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
    if (d / "eval.json").exists() and _read_json(d / "eval.json").get("_meta", {}).get("evaluator_id") != want_id:
        return "evaluate"
    if (d / "eval.json").exists() and _scored_block(d / "eval.json") != cfg.rprec_block:
        return "block"
    return None


def is_complete(cfg: SweepConfig, spec: RunSpec) -> bool:
    st = stage_state(cfg, spec)
    return st["train"] and (not cfg.evaluator or st["evaluate"])


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}


def _update_json(path: Path, **kv) -> None:
    atomic_write_json(path, {**_read_json(path), **kv})


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
            _update_json(status, status="done", error=None)
            return stage_state(cfg, spec)
        _update_json(status, status="running", error=None, host=socket.gethostname(), pid=os.getpid(),
                     slurm_job=os.environ.get("SLURM_JOB_ID"))
        prov_path = d / "provenance.json"
        prov = _read_json(prov_path)
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
        if cfg.evaluator:
            stale = stale_scores(cfg, d)
            if stale and (d / "eval.json").exists():
                # Keep the old yardstick's scores beside the new ones (nothing written is lost).
                keep = _keep_old_scores(d, cfg.rprec_block)
                why = (f"at R-Precision block {_scored_block(keep)}, not {cfg.rprec_block}" if stale == "block"
                       else f"by evaluator {_read_json(keep).get('_meta', {}).get('evaluator_id') or 'unrecorded'}, "
                            f"not {evaluator_identity(cfg.evaluator)[0]}")
                print(f"   {spec.name}: scored {why}: {'regenerating and ' if stale == 'generate' else ''}"
                      f"rescoring (old scores kept in {keep.name})", flush=True)
            if not state["generate"]:
                # Prompt at the caption level the evaluator scores (its text policy), so that the
                # generated file's captions are the ones the evaluator embeds.
                level = json.loads((Path(cfg.evaluator) / "evaluator.json").read_text())["text"]["eval_level"]
                stage("generate", _subst(["handx", "generate", "--run", str(d), "--data", cfg.data, "--split",
                                          cfg.eval_split, "--level", str(level), "--limit", str(cfg.eval_limit),
                                          "--samples", str(cfg.eval_samples),
                                          *(a for o in generate_settings(cfg, spec) for a in ("--set", o)),
                                          "--out", str(d / "generated.npz")], {}))
            if not state["evaluate"]:
                stage("evaluate", _subst(["handx", "eval", "run", "--evaluator", cfg.evaluator, "--generated",
                                          str(d / "generated.npz"), "--data", cfg.data, "--block",
                                          str(cfg.rprec_block), "--json", "--out", str(d)], {}))
        _update_json(status, status="done", error=None)
        return stage_state(cfg, spec)
    except BaseException as e:
        _update_json(status, status="failed", error=f"{type(e).__name__}: {e}"[-4000:])
        raise
    finally:
        lock.release()


# ------------------------------------------------------------------------------------------------
# Results


def _spec_of(doc: dict) -> RunSpec:
    return RunSpec(**{**doc, "overrides": tuple(doc.get("overrides", ())),
                      "needs": tuple(Step(s["name"], tuple(tuple(c) for c in s["commands"]), s.get("version", "1"),
                                          s.get("family", ""))
                                     for s in doc.get("needs", ())),
                      "args": tuple(doc.get("args", ())), "command": tuple(doc.get("command", ()))})


def run_status(out: Path, cfg: SweepConfig, spec: RunSpec, slurm_active: dict | None = None) -> tuple[str, str | None]:
    """done | running | failed | pending (and the error of a failed run).

    ``slurm_active`` ({job id: state} from squeue) tells a queued job (pending) from a running one.
    """
    d = run_dir(cfg, spec)
    if is_complete(cfg, spec):
        return "done", None
    st = _read_json(d / "status.json")
    job = _read_json(out / "slurm_jobs.json").get(spec.name)
    if slurm_active is not None and job in slurm_active and slurm_active[job] == "PENDING" and not is_locked(d):
        return "pending", f"queued as SLURM job {job}"
    if is_locked(d) or (slurm_active is not None and job in slurm_active):
        return "running", None
    if st.get("status") in ("failed", "running"):  # "running" with no live holder: it died
        return "failed", st.get("error") or "the process running it ended before it finished"
    stale = stale_scores(cfg, d)
    if stale:
        return "pending", {"generate": "samples prompted at another caption level than the evaluator scores: "
                                       "regenerate and rescore",
                           "evaluate": "scored by another evaluator: rescore",
                           "block": f"scored at R-Precision block {_scored_block(d / 'eval.json')}, the sweep's is "
                                    f"{cfg.rprec_block}: rescore"}[stale]
    return "pending", None


def result_row(out: Path, cfg: SweepConfig, spec: RunSpec, slurm_active: dict | None = None) -> dict:
    from analysis.schema import COLUMN_BY_NAME, row_from_run_dir, validate_row

    d = run_dir(cfg, spec)
    status, error = run_status(out, cfg, spec, slurm_active)
    if (d / "config.json").exists() and (d / "metrics.jsonl").exists():
        row = {k: v for k, v in row_from_run_dir(d).items() if v is not None}
        cdoc = _read_json(d / "config.json")
        from handx_jax.families import flops_columns

        for k, v in flops_columns(cdoc).items():
            row.setdefault(k, v)
        if isinstance(cdoc.get("data"), dict) and cdoc["data"].get("sampling"):
            row.setdefault("data_sampling", cdoc["data"]["sampling"])
    else:
        row = {"run_id": spec.name, "family": spec.family}
    row["run_id"] = spec.name
    for k, v in spec.axes.items():
        if k in COLUMN_BY_NAME:
            row.setdefault(k, v)
    prov = _read_json(d / "provenance.json")
    secs = sum(s.get("seconds", 0.0) for s in prov.get("stages", {}).values())
    if status != "failed":
        error = None  # e.g. "queued as SLURM job ..." is a note for `handx sweep status`, not a failure
    if error:  # one line in the table (the full text stays in RUN/status.json and RUN/logs/)
        lines = [ln.strip() for ln in error.splitlines() if ln.strip()]
        error = " | ".join(lines[:1] + lines[-3:] if len(lines) > 4 else lines)[:600]
    row.update(sweep=cfg.name or out.name, status=status, error=error)
    if prov:
        row.update(wall_time_s=secs, device_kind=prov.get("device_kind"), git_commit=prov.get("git_commit"))
    return validate_row({k: v for k, v in row.items() if v is not None}, path=d, row=spec.name)


def _load_state(out: Path) -> tuple[SweepConfig, list[RunSpec]]:
    """The sweep's config and runs from ``out/sweep.json``. Its ``out`` is the folder read, not the path the
    launch was given: a relative ``--out`` names another folder from another working directory (or after
    the sweep folder moved), and collecting from there would rewrite the table with every run missing."""
    path = Path(out) / "sweep.json"
    if not path.exists():
        raise DataError("not a sweep folder (no sweep.json); run `handx sweep run ... --out` first", path=out)
    doc = read_json(path)  # corrupt: a DataError naming the file, not "(no sweep.json)"
    if not isinstance(doc, dict) or not isinstance(doc.get("config"), dict) or not isinstance(doc.get("runs"), list):
        raise DataError("not a sweep record: expected an object with 'config' and 'runs' (rewritten by the next "
                        "`handx sweep run ... --out`)", path=path)
    try:
        conf = dict(doc["config"])
        if "sampler" in conf or "sampler_steps" in conf:  # recorded before generation settings were sample.*
            conf["sample"] = (f"sample.sampler={conf.pop('sampler', 'ddim')}",
                              f"sample.steps={conf.pop('sampler_steps', 50)}")
        cfg = SweepConfig(**{**conf, "sample": tuple(conf.get("sample", ())), "out": str(Path(out).absolute())})
        specs = [_spec_of(s) for s in doc["runs"]]
    except (TypeError, KeyError, AttributeError, ValueError) as e:
        raise DataError(f"damaged sweep record ({_one_line(e)}); rerun `handx sweep run ... --out` to rewrite it",
                        path=path) from None
    return cfg, specs


def collect_results(out: str | os.PathLike, slurm_active: dict | None = None) -> Path:
    """Rebuild OUT/results.jsonl and OUT/results.csv (atomically), one row per run of the sweep."""
    from analysis.schema import save_results

    out = Path(out)
    if not out.is_dir():
        raise FileNotFoundError(f"no sweep folder {out} (refusing to create it; check the path)")
    cfg, specs = _load_state(out)
    rows = [result_row(out, cfg, s, slurm_active) for s in specs]
    save_results(out / "results.csv", rows)
    return save_results(out / "results.jsonl", rows)


_COLLECT = threading.Lock()


def _collect_quietly(out: Path) -> None:
    with _COLLECT:
        try:
            collect_results(out)
        except Exception as e:  # a bad row must not stop the sweep; the final collect raises
            print(f"   (results not updated: {e})", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------------------------
# Executors


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
        _collect_quietly(out)

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
    old = _read_json(jobs_path)
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
        atomic_write_json(jobs_path, {**_read_json(jobs_path), **{s.name: ids[s.name] for s in submit}})
    # Wait for every job (not just the first to fail), refreshing the table as runs finish.
    waiting = set(ids.values())
    seen_done: set[str] = set()
    while waiting:
        waiting = set(squeue_states(sorted(waiting)))
        done_now = {s.name for s in todo if is_complete(cfg, s)} - seen_done
        if done_now:
            seen_done |= done_now
            _collect_quietly(out)
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
        st = _read_json(run_dir(cfg, s) / "status.json")
        state = final.get(ids[s.name], "unknown (no accounting)")
        err = st.get("error") if st.get("status") == "failed" else None
        failed[s.name] = (f"SLURM job {ids[s.name]} ended in state {state} before the run finished"
                          + (f": {err}" if err else ""))
        _update_json(run_dir(cfg, s) / "status.json", status="failed", error=failed[s.name])
    return failed


def launch(specs: Sequence[RunSpec], cfg: SweepConfig) -> LaunchResult:
    """Run every spec (skipping finished stages); return the results table and the runs that failed."""
    out = Path(cfg.out).absolute()
    from handx_jax.families import entry

    for s in specs:
        run_dir(cfg, s)  # refuses names that would leave OUT
    for s in specs:
        try:
            entry(s.family)  # every run names a registered family (its results row says which)
        except ValueError as e:
            raise ValueError(f"run {s.name}: {e}") from None
    if cfg.executor == "slurm" and "timeout_min" not in cfg.slurm:
        raise ValueError("SLURM needs a time limit: give timeout_min in the sweep's RESOURCES for this preset or "
                         "--slurm timeout_min=N (submitit's silent default would end every run after 5 minutes)")
    out.mkdir(parents=True, exist_ok=True)
    prev = _read_json(out / "sweep.json").get("runs", [])
    names = {s.name for s in specs}
    # Keep the runs of earlier launches (e.g. `--only`) in the table, in their order, then the new ones.
    runs = [r for r in prev if r["name"] not in names] + [dataclasses.asdict(s) for s in specs]
    atomic_write_json(out / "sweep.json", {"config": dataclasses.asdict(cfg), "runs": runs})
    if cfg.executor == "local":
        failed = _local(specs, cfg, out)
    elif cfg.executor == "slurm":
        failed = _slurm(specs, cfg, out)
    elif cfg.executor == "debug":
        ex = _submitit().AutoExecutor(folder=str(out / "submitit"), cluster="debug")
        failed = {}
        for s in specs:
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
    cfg, specs = _load_state(out)
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
    doc = _read_json(out / "sweep.json")  # launch put the relaunched runs last: restore the sweep's order
    order = {s.name: i for i, s in enumerate(specs)}
    doc["runs"].sort(key=lambda r: order.get(r["name"], len(order)))
    atomic_write_json(out / "sweep.json", doc)
    return LaunchResult(collect_results(out), res.failed)


def status(out: str | os.PathLike) -> list[dict]:
    """Per run: name, stages done, and done | running | failed | pending."""
    out = Path(out)
    if not out.is_dir():
        raise FileNotFoundError(f"no sweep folder {out}")
    cfg, specs = _load_state(out)
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
