"""What a sweep is: run and step specs, their names and hashes, and loading a sweep file.

A sweep file is plain Python: ``runs(preset=..., **kw) -> list[RunSpec]`` (``sweeps/launcher.py`` tells the
whole story); ``Step`` is a shared step named from a hash of its commands (computed once, found again by
every run that needs it); ``RunSpec`` one point; ``axes_of``/``run_id`` its axis values and folder name;
``SweepConfig`` the launch settings.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from handx_jax.infra.errors import DataError

REPO = Path(__file__).resolve().parent.parent
# A run or step name is one path component: no separators, no "..", nothing hidden.
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._=+,-]{0,127}$")


def check_name(name: str, what: str = "run") -> str:
    if not isinstance(name, str) or not NAME_RE.match(name) or ".." in name:
        raise DataError(f"{what} name {name!r} is not allowed: use letters, digits and . _ = + , - "
                        f"(no '/', no '..', at most 128 characters), so that it stays inside --out")
    return name


# Commands renamed since steps were first hashed (issue 42), today's spelling → the one the key hashes: a
# step's key names what it computes, so a finished step, and every run named after it (the AR LMs' ids
# carry their tokenizer step's key), is found again after a rename instead of recomputed.
_FIRST_SPELLING: dict[tuple[str, ...], tuple[str, ...]] = {("handx", "data", "tokens"): ("handx", "tokenize")}


def _as_first_spelled(cmd: Sequence[str]) -> list[str]:
    for new, old in _FIRST_SPELLING.items():
        if tuple(cmd[:len(new)]) == new:
            return [*old, *cmd[len(new):]]
    return list(cmd)


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
        doc = json.dumps({"name": self.name, "commands": [_as_first_spelled(c) for c in self.commands],
                          "version": self.version}, sort_keys=True)
        return f"{self.name}-{hashlib.sha256(doc.encode()).hexdigest()[:12]}"


def family_step(family: str, name: str, preset: str, overrides: Sequence[str] = ()) -> Step:
    """A shared step that trains one run of ``family`` (e.g. the AR LM's tokenizer, keyed by its
    ``model.codebook``) and runs the registry's ``after_train`` commands on it (the token cache)."""
    from handx_jax.families import entry

    fam = entry(family)
    train = ("handx", "train", family, "--data", "{data}", *(("--encoder", "{encoder}") if fam.encoder else ()),
             "--preset", preset, *(a for o in overrides for a in ("--set", o)), "--out", "{out}", "--quiet")
    return Step(name, (train, *fam.after_train), family=family)


# The axes every family's runs share (column → config key, and → its letter in run ids); a family adds
# its own in the registry (``Family.axes``: the AR codebook).
SHARED_AXES = {"layers": "model.layers", "dim": "model.dim", "heads": "model.heads", "ff": "model.ff",
               "data_fraction": "data.fraction"}
SHORT = {"layers": "L", "dim": "d", "heads": "H", "ff": "ff", "data_fraction": "f", "data_sampling": "s"}


def axes_of(overrides: Sequence[str], *names: str) -> dict:
    """A point's axis values read from its own overrides (``model.layers=4`` → ``{"layers": 4}``), so a
    value such as the data fraction is written once, as the override, and the row and the run id follow."""
    from handx_jax.families import family_axes

    keys = {**SHARED_AXES, **{a.name: a.key for a in family_axes().values()}}
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
    from handx_jax.families import family_axes

    short = {**SHORT, **{a.name: a.short for a in family_axes().values()}}
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
        raise DataError(f"sweep file failed to import: {one_line(e)}", path=path) from None
    if not callable(getattr(mod, "runs", None)):
        raise DataError("sweep file defines no runs(**kw) function", path=path)
    return mod


def one_line(e: BaseException) -> str:
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
        raise DataError(f"{call} raised {one_line(e)}", path=path) from None
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
