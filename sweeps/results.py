"""A sweep's results table: one row per run (status, axes, the run folder's own row), rebuilt atomically
as OUT/results.jsonl and OUT/results.csv after every run (``collect_results``).
"""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_json
from handx_jax.infra.runlock import is_locked
from sweeps.spec import RunSpec, Step, SweepConfig, one_line
from sweeps.stages import is_complete, read_json_or_empty, run_dir, scored_block, stale_scores

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
    st = read_json_or_empty(d / "status.json")
    job = read_json_or_empty(out / "slurm_jobs.json").get(spec.name)
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
                           "block": f"scored at R-Precision block {scored_block(d / 'eval.json')}, the sweep's is "
                                    f"{cfg.rprec_block}: rescore"}[stale]
    return "pending", None


# The prediction benchmark's columns (``handx eval prediction``'s "predicted" row: every frame after the
# observation), taken into the results row of a run scored on prediction (``Family.sweep_task``).
PREDICTION_COLUMNS = tuple(f"{m}_{h}" for m in ("mpjpe_ra", "mpjpe_pa", "apd") for h in ("left", "right"))


def prediction_columns(d: Path) -> dict:
    """A run folder's prediction scores (``RUN/eval_prediction.json``) as results columns; {} without one. They
    replace the same columns of ``eval.json``, which the evaluator computes over whole clips, observed
    frames included."""
    pred = read_json_or_empty(d / "eval_prediction.json").get("predicted") or {}
    out = {}
    for c in PREDICTION_COLUMNS:
        if isinstance(pred.get(c), (int, float)):
            out[c] = float(pred[c])
            if isinstance(pred.get(f"{c}_ci"), (int, float)):
                out[f"{c}_ci"] = float(pred[f"{c}_ci"])
    return out


# BimArt's hand-object scores (``handx eval objects``), taken into the row of a run scored on object2motion.


def object_columns(d: Path) -> dict:
    """A run folder's hand-object scores (``RUN/eval_objects.json``) as results columns; {} without one (NaN
    scores, e.g. Mul of one sample, are left out)."""
    from analysis.schema.columns import OBJECT_METRICS

    doc = read_json_or_empty(d / "eval_objects.json")
    cols = [x for c in OBJECT_METRICS for x in (c, f"{c}_ci")]
    return {c: float(doc[c]) for c in cols if isinstance(doc.get(c), (int, float)) and doc[c] == doc[c]}


def result_row(out: Path, cfg: SweepConfig, spec: RunSpec, slurm_active: dict | None = None) -> dict:
    from analysis.schema import column_by_name, row_from_run_dir, validate_row

    d = run_dir(cfg, spec)
    status, error = run_status(out, cfg, spec, slurm_active)
    if (d / "config.json").exists() and (d / "metrics.jsonl").exists():
        row = {k: v for k, v in row_from_run_dir(d).items() if v is not None}
        cdoc = read_json_or_empty(d / "config.json")
        from handx_jax.families import flops_columns

        for k, v in flops_columns(cdoc).items():
            row.setdefault(k, v)
        if isinstance(cdoc.get("data"), dict) and cdoc["data"].get("sampling"):
            row.setdefault("data_sampling", cdoc["data"]["sampling"])
    else:
        row = {"run_id": spec.name, "family": spec.family}
    row.update(prediction_columns(d))
    row.update(object_columns(d))
    row["run_id"] = spec.name
    known = column_by_name()
    for k, v in spec.axes.items():
        if k in known:
            row.setdefault(k, v)
    prov = read_json_or_empty(d / "provenance.json")
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


def load_state(out: Path) -> tuple[SweepConfig, list[RunSpec]]:
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
        raise DataError(f"damaged sweep record ({one_line(e)}); rerun `handx sweep run ... --out` to rewrite it",
                        path=path) from None
    return cfg, specs


def collect_results(out: str | os.PathLike, slurm_active: dict | None = None) -> Path:
    """Rebuild OUT/results.jsonl and OUT/results.csv (atomically), one row per run of the sweep."""
    from analysis.schema import save_results

    out = Path(out)
    if not out.is_dir():
        raise FileNotFoundError(f"no sweep folder {out} (refusing to create it; check the path)")
    cfg, specs = load_state(out)
    rows = [result_row(out, cfg, s, slurm_active) for s in specs]
    save_results(out / "results.csv", rows)
    return save_results(out / "results.jsonl", rows)


_COLLECT = threading.Lock()


def collect_quietly(out: Path) -> None:
    with _COLLECT:
        try:
            collect_results(out)
        except Exception as e:  # a bad row must not stop the sweep; the final collect raises
            print(f"   (results not updated: {e})", file=sys.stderr, flush=True)
