"""The results table: one row per run, the files it is stored in, and the run-folder contract.

Results table
-------------
A results table is a list of rows; a row is a plain ``dict`` keyed by the column names in
:data:`COLUMNS` (every column present, ``None`` where unknown). Rows come from

* ``results.jsonl`` -- one JSON object per line, holding any subset of the columns;
* ``results.csv``   -- a header line with column names, then one line per run; an empty cell is a
  missing value and lines starting with ``#`` are comments;
* a run folder (below), or a sweep folder whose sub-folders are run folders.

Unknown columns are an error (a misspelled metric must not vanish silently), and so are values of
the wrong type; :class:`handx_jax.io.DataError` names the file, the row and the column.

Columns (see :data:`COLUMNS` for the full list and units):

* identity: ``run_id`` (unique across all files loaded together), ``family`` (``diffusion``, ``ar``,
  ``evaluator`` or ``ground_truth`` -- the latter marks the reference row of a table), ``label``;
* axes: ``layers``, ``dim``, ``heads``, ``ff``, ``codebook``, ``data_fraction``;
* size and compute: ``params``, ``params_non_embedding`` (trainable, frozen text encoder excluded,
  as in the paper's Table C), ``flops_per_sample`` (forward FLOPs of the trainable model for one
  training sample -- the x-axis of the paper's Fig. 4 / Table B), ``text_flops_per_sample`` (forward
  FLOPs of the frozen text encoder for one sample), ``train_flops`` (total training compute spent),
  ``steps``, ``samples_seen``;
* metrics: each name in :data:`METRICS` as ``<name>`` (the point value) and ``<name>_ci`` (its
  half-width: whatever the evaluator reports as the ± value; the paper's ± values are kept as
  printed); ``rprec_block`` (R-Precision block size, so chance top-k = k/block); ``evaluator`` and
  ``evaluator_id`` (which evaluator scored the row, from ``eval.json``'s ``_meta``);
* the paper's FLOPs convention: ``flops_per_sample_paper`` (multiply-adds of the Linear layers plus the
  frozen text encoder, which reproduces Table B; ``handx_jax/families/diffusion/flops.py``) and its text-encoder part
  ``text_flops_per_sample_paper``, beside the analytic ``flops_per_sample``;
* launcher provenance (``sweeps/launcher.py``): ``sweep``, ``status`` (done | failed | running |
  pending), ``error``, ``data_sampling`` (clips | pairs), ``wall_time_s``, ``device_kind``,
  ``git_commit``.

``load_results(..., strict=False)`` (what ``handx analyze fit/plot/extrapolate`` use) accepts any
table with the columns an analysis names: unknown columns are kept, only schema columns are checked.

Run-folder contract
-------------------
The training loop writes, and :func:`row_from_run_dir` reads, a folder holding:

``config.json`` (required)
    A JSON object: the run's full configuration. Schema columns are looked up by name at the top
    level, then in the sub-objects ``"model"`` and ``"data"`` (so a config composed from parts
    works); the same key with two different values is an error. Keys that are not schema columns
    (learning rate, seed, ...) are ignored: this is the training config, not a results row.
    ``family`` is required. ``run_id`` defaults to the folder name.
``metrics.jsonl`` (required)
    One JSON object per logged step, each with an integer ``"step"``; any other keys. The row takes
    ``steps``, ``samples_seen`` and ``train_flops`` from the last line (highest step) that has
    them; ``params``, ``params_non_embedding``, ``flops_per_sample`` and
    ``text_flops_per_sample`` may also be logged here (e.g. at init) when config.json lacks them.
    ``train_flops`` is the *cumulative* training compute. If no line logs it, it is estimated as
    ``3 * flops_per_sample * samples_seen`` (forward + backward of the trainable model; the frozen
    text encoder's outputs are cached and cost no training compute). A torn last line (a run killed
    mid-write) is skipped.
``eval.json`` (optional)
    A JSON object mapping metric names (:data:`METRICS`) to ``{"mean": x, "ci": y}`` (``ci``
    optional), to ``[mean, ci]`` (what ``json.dump`` makes of ``handx_jax.metrics.mean_ci``'s
    tuple), or to a plain number. ``<name>_ci`` keys are also accepted. Keys starting with ``_``
    (e.g. ``"_meta": {"step": 1000, "checkpoint": "..."}``) are ignored; any other key is an error.
"""

from __future__ import annotations

import csv
import difflib
import io
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from handx_jax.io import DataError, atomic_write_jsonl, atomic_write_text, read_jsonl

# The metrics the evaluator reports (reference §5.4; paper Tables 2, 3, B, D), named as the keys of
# handx_jax.metrics.replicate_embedding_metrics / replicate_motion_metrics.
METRICS: tuple[str, ...] = (
    "rprec_top1", "rprec_top2", "rprec_top3",
    "fid", "diversity", "mm_dist", "multimodality", "mpjpe", "acceleration", "jitter",
    "contact_precision_intra", "contact_recall_intra", "contact_f1_intra",
    "contact_precision_inter", "contact_recall_inter", "contact_f1_inter",
    # G-HTT §4.2 (mm, per hand): root-aligned and Procrustes-aligned MPJPE, APD over a prompt's samples;
    # BimArt §4: % of frames with inter-hand penetration > 1 cm, mean depth (mm), contact feasibility.
    "mpjpe_ra_left", "mpjpe_ra_right", "mpjpe_pa_left", "mpjpe_pa_right", "apd_left", "apd_right",
    "pen_1cm", "pen_depth", "contact_feasibility",
)
LOWER_IS_BETTER: frozenset[str] = frozenset({"fid", "mm_dist", "mpjpe", "mpjpe_ra_left", "mpjpe_ra_right",
                                             "mpjpe_pa_left", "mpjpe_pa_right", "pen_1cm", "pen_depth"})
# No direction: the best value is the one closest to the ground truth's (paper Tables 2/3).
# Acceleration or jitter below the data's means over-smoothed motion, not better motion, so the best
# value for them is also the one closest to the ground truth.
CLOSEST_TO_GT: frozenset[str] = frozenset({"diversity", "multimodality", "acceleration", "jitter"})
GROUND_TRUTH = "ground_truth"
# Rows that are not a model family's runs; the families themselves are the registry's
# (handx_jax.families, a light module: no JAX is imported).
ROW_KINDS: tuple[str, ...] = ("evaluator", GROUND_TRUTH)


def families() -> list[str]:
    """Every value the ``family`` column may take: the registered families, then ``ROW_KINDS``."""
    from handx_jax.families import names

    return [*names(), *ROW_KINDS]


@dataclass(frozen=True)
class Column:
    name: str
    kind: type  # str, int or float
    doc: str
    required: bool = False
    positive: bool = False  # for numbers: must be > 0
    nonnegative: bool = False


def _metric_columns() -> list[Column]:
    cols = []
    for m in METRICS:
        cols.append(Column(m, float, f"metric {m} (point value)"))
        cols.append(Column(f"{m}_ci", float, f"half-width of the ± interval of {m}", nonnegative=True))
    return cols


COLUMNS: tuple[Column, ...] = (
    Column("run_id", str, "unique id of the run", required=True),
    Column("family", str, "model family (the registry, handx_jax.families) | evaluator | ground_truth",
           required=True),
    Column("label", str, "free-text display label"),
    Column("layers", int, "transformer layers (L)", positive=True),
    Column("dim", int, "model width (d)", positive=True),
    Column("heads", int, "attention heads (H)", positive=True),
    Column("ff", int, "feed-forward width (FFN)", positive=True),
    Column("codebook", int, "FSQ codebook size (AR family)", positive=True),
    Column("data_fraction", float, "fraction of the training split used, in (0, 1]", positive=True),
    Column("params", int, "trainable parameters (frozen text encoder excluded)", positive=True),
    Column("params_non_embedding", int, "trainable parameters without embeddings", positive=True),
    Column("flops_per_sample", float, "forward FLOPs of the trainable model per sample (analytic convention: "
           "2 per multiply-add of every matmul, text encoder excluded)", positive=True),
    Column("text_flops_per_sample", float, "forward FLOPs of the frozen text encoder per sample",
           nonnegative=True),
    Column("flops_per_sample_paper", float, "per-sample FLOPs in the paper's Table B convention: multiply-adds of "
           "the denoiser's Linear layers plus the frozen text encoder's (handx_jax/families/diffusion/flops.py)", positive=True),
    Column("text_flops_per_sample_paper", float, "the text-encoder part of flops_per_sample_paper (MACs)",
           nonnegative=True),
    Column("train_flops", float, "total training compute (FLOPs)", nonnegative=True),
    Column("steps", int, "optimizer steps run", nonnegative=True),
    Column("samples_seen", int, "training samples processed", nonnegative=True),
    Column("seed", int, "training seed (initialisation and data order); rows that differ only in it are "
           "replicates (handx analyze fit --mean-replicates)", nonnegative=True),
    Column("rprec_block", int, "R-Precision block size (32: Tables 2/3, 16: Table B); chance top-k = k/block",
           positive=True),
    Column("evaluator", str, "the evaluator that scored the row: standard-vN for the packaged one, else its id"),
    Column("evaluator_id", str, "identity of the scoring evaluator's weights and config "
           "(handx_jax.evaluation.evaluator_id); rows with different ids are on different yardsticks"),
    *_metric_columns(),
    # Provenance of a launcher row (sweeps/launcher.py).
    Column("sweep", str, "sweep name"),
    Column("status", str, "launcher status: done | trained | failed | running | pending"),
    Column("error", str, "why the run failed (launcher rows)"),
    Column("data_sampling", str, "how training items are drawn: clips (nested clip subsets) | pairs"),
    Column("wall_time_s", float, "wall-clock seconds the run's stages took", nonnegative=True),
    Column("device_kind", str, "accelerator the run trained on (jax.devices()[0].device_kind)"),
    Column("git_commit", str, "git commit of the code that trained the run"),
)
COLUMN_BY_NAME: dict[str, Column] = {c.name: c for c in COLUMNS}
COLUMN_NAMES: tuple[str, ...] = tuple(c.name for c in COLUMNS)
NUMERIC_COLUMNS: tuple[str, ...] = tuple(c.name for c in COLUMNS if c.kind is not str)


def _where(path: Any, row: Any) -> str:
    parts = []
    if path is not None:
        parts.append(f"file {os.fspath(path)}")
    if row is not None:
        parts.append(f"row {row}")
    return ", ".join(parts)


def _error(msg: str, *, path: Any = None, row: Any = None, column: str | None = None) -> DataError:
    where = _where(path, row)
    if column is not None:
        where = f"{where}, column {column!r}" if where else f"column {column!r}"
    err = DataError(f"{where}: {msg}" if where else msg)
    err.path, err.field = path, column
    return err


def _coerce(col: Column, value: Any, *, path: Any, row: Any) -> Any:
    """Parse one cell (JSON value or CSV string) into the column's type; None means missing."""
    if value is None:
        return None
    if isinstance(value, str):
        s = value.strip()
        if s == "" or s.lower() in ("nan", "none", "null"):
            return None if col.kind is not str or s == "" else s
        if col.kind is str:
            return s
        try:
            num = float(s.replace("_", ""))
        except ValueError:
            raise _error(f"expected a number, got {value!r}", path=path, row=row, column=col.name) from None
    elif col.kind is str:
        raise _error(f"expected a string, got {type(value).__name__} {value!r}", path=path, row=row,
                     column=col.name)
    elif isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise _error(f"expected a number, got {type(value).__name__} {value!r}", path=path, row=row,
                     column=col.name)
    else:
        num = float(value)
        if math.isnan(num):
            return None
    if not math.isfinite(num):
        raise _error(f"value must be finite, got {value!r}", path=path, row=row, column=col.name)
    if col.kind is int:
        if num != round(num):
            raise _error(f"expected an integer, got {value!r}", path=path, row=row, column=col.name)
        out: Any = int(round(num))
    else:
        out = num
    if col.positive and not out > 0:
        raise _error(f"must be > 0, got {value!r}", path=path, row=row, column=col.name)
    if col.nonnegative and out < 0:
        raise _error(f"must be >= 0, got {value!r}", path=path, row=row, column=col.name)
    return out


def _unknown_column(name: str, *, path: Any, row: Any) -> DataError:
    close = difflib.get_close_matches(name, COLUMN_NAMES, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return _error(f"unknown column{hint}; known columns: {', '.join(COLUMN_NAMES)}", path=path, row=row,
                  column=name)


def _is_nan(v: Any) -> bool:
    if isinstance(v, str):
        return v.strip().lower() == "nan"
    return isinstance(v, (float, np.floating)) and v != v


def validate_row(raw: Mapping[str, Any], *, path: Any = None, row: Any = None) -> dict[str, Any]:
    """Check one raw row and return it as a full row (every column, None where missing)."""
    if not isinstance(raw, Mapping):
        raise _error(f"expected an object, got {type(raw).__name__}", path=path, row=row)
    unknown = [k for k in raw if k not in COLUMN_BY_NAME]
    if unknown:
        raise _unknown_column(unknown[0], path=path, row=row)
    out = {c.name: _coerce(c, raw.get(c.name), path=path, row=row) for c in COLUMNS}
    for c in COLUMNS:
        if c.required and out[c.name] is None:
            raise _error("required value is missing", path=path, row=row, column=c.name)
    if out["family"] not in families():
        raise _error(f"unknown family {out['family']!r}; expected one of {families()}", path=path,
                     row=row, column="family")
    if out["data_fraction"] is not None and out["data_fraction"] > 1:
        raise _error(f"must be in (0, 1], got {out['data_fraction']}", path=path, row=row,
                     column="data_fraction")
    for m in METRICS:
        # A NaN value is not a missing one: it is there but unusable, which the analysis that reads the row
        # reports or drops (fits.unusable_values, fits.select_rows), naming the cell.
        if out[f"{m}_ci"] is not None and out[m] is None and not _is_nan(raw.get(m)):
            raise _error(f"{m}_ci is given but {m} is not", path=path, row=row, column=f"{m}_ci")
    return out


def lenient_row(raw: Mapping[str, Any], *, path: Any = None, row: Any = None) -> dict[str, Any]:
    """An analyst's row: schema columns are type-checked, other columns kept (numbers parsed).

    For ``handx analyze fit/plot`` on any table with the named columns: no required columns beyond
    what the command uses (``run_id`` defaults to the row number, ``family`` to None = a run).
    """
    if not isinstance(raw, Mapping):
        raise _error(f"expected an object, got {type(raw).__name__}", path=path, row=row)
    out: dict[str, Any] = {c.name: None for c in COLUMNS}
    for k, v in raw.items():
        k = str(k).strip()
        if k in COLUMN_BY_NAME:
            out[k] = _coerce(COLUMN_BY_NAME[k], v, path=path, row=row)
        elif isinstance(v, str):
            try:
                num = float(v.replace("_", "")) if v.strip() else None
            except ValueError:
                num = v
            out[k] = num
        else:
            out[k] = v
    if out["run_id"] is None:
        out["run_id"] = f"{Path(path).name if path is not None else 'row'}:{row}"
    return out


class Row(dict):
    """A results row that remembers where it was read: ``source`` (``file PATH, row N``), that ``file`` and
    ``line`` (its row, 1-based) apart, and ``cells`` (the raw cells as read, before NaN and empty cells
    became None), so an analysis that leaves the row out can say where it is and why (its cell was NaN or
    empty, or the file has no such column)."""

    __slots__ = ("source", "cells", "file", "line")

    def __init__(self, values: Mapping[str, Any], *, source: str | None = None,
                 cells: Mapping[str, Any] | None = None, file: str | None = None, line: int | None = None):
        super().__init__(values)
        self.source, self.cells, self.file, self.line = source, cells, file, line


def make_row(**values: Any) -> dict[str, Any]:
    """Build a validated row from keyword arguments (handy in code and tests)."""
    return validate_row(values)


# ----------------------------------------------------------------------------------------------
# Loading and saving


def _load_jsonl(path: Path, strict: bool = True) -> list[dict[str, Any]]:
    raws = read_jsonl(path)
    check = validate_row if strict else lenient_row
    return [Row(check(r, path=path, row=i + 1), source=_where(path, i + 1), cells=r if isinstance(r, dict) else None,
                file=os.fspath(path), line=i + 1) for i, r in enumerate(raws)]


def _load_csv(path: Path, strict: bool = True) -> list[dict[str, Any]]:
    text = path.read_text(encoding="utf-8")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        return []
    reader = csv.reader(lines)
    header = [h.strip() for h in next(reader)]
    for h in header if strict else ():
        if h not in COLUMN_BY_NAME:
            raise _unknown_column(h, path=path, row="header")
    if len(set(header)) != len(header):
        raise _error("duplicate column in the CSV header", path=path, row="header")
    rows = []
    for i, cells in enumerate(reader):
        if len(cells) != len(header):
            raise _error(f"has {len(cells)} cells but the header has {len(header)}", path=path, row=i + 1)
        raw = dict(zip(header, cells))
        rows.append(Row((validate_row if strict else lenient_row)(raw, path=path, row=i + 1),
                        source=_where(path, i + 1), cells=raw, file=os.fspath(path), line=i + 1))
    return rows


def load_results(*paths: str | os.PathLike, strict: bool = True) -> list[dict[str, Any]]:
    """Load and concatenate results tables (.jsonl, .csv, run folders or sweep folders).

    ``run_id`` must be unique over everything loaded together. ``strict=False`` accepts any table
    with the columns an analysis needs (an analyst's own numbers): unknown columns are kept, and
    only schema columns are type-checked (:func:`lenient_row`).
    """
    rows: list[dict[str, Any]] = []
    seen: dict[str, str] = {}
    for p in paths:
        path = Path(p)
        if path.is_dir():
            part = _load_dir(path)
        elif not path.exists():
            raise DataError("no such file or directory", path=path)
        elif path.suffix == ".jsonl":
            part = _load_jsonl(path, strict)
        elif path.suffix == ".csv":
            part = _load_csv(path, strict)
        else:
            raise DataError("unsupported results file; expected .jsonl, .csv or a run folder", path=path)
        for r in part:
            if r["run_id"] in seen:
                raise DataError(f"run_id {r['run_id']!r} appears twice (also in {seen[r['run_id']]})",
                                path=path, field="run_id")
            seen[r["run_id"]] = str(path)
        rows.extend(part)
    return rows


def _load_dir(path: Path) -> list[dict[str, Any]]:
    if (path / "config.json").exists():
        return [row_from_run_dir(path)]
    for name in ("results.jsonl", "results.csv"):
        if (path / name).exists():
            return load_results(path / name)
    subs = sorted(d for d in path.iterdir() if d.is_dir() and (d / "config.json").exists())
    if not subs:
        raise DataError("not a run folder (no config.json), has no results.jsonl/.csv and no run "
                        "sub-folders", path=path)
    return [row_from_run_dir(d) for d in subs]


def _used_columns(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    return [c.name for c in COLUMNS if c.required or any(r.get(c.name) is not None for r in rows)]


def _format_cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)  # shortest string that round-trips exactly
    return str(v)


def rows_to_csv(rows: Sequence[Mapping[str, Any]]) -> str:
    rows = [validate_row(r, row=i + 1) for i, r in enumerate(rows)]
    cols = _used_columns(rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow([_format_cell(r[c]) for c in cols])
    return buf.getvalue()


def save_results(path: str | os.PathLike, rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write rows to ``.jsonl`` (missing values omitted) or ``.csv`` (used columns only), atomically."""
    path = Path(path)
    rows = [validate_row(r, path=path, row=i + 1) for i, r in enumerate(rows)]
    if path.suffix == ".jsonl":
        return atomic_write_jsonl(path, ({k: v for k, v in r.items() if v is not None} for r in rows))
    if path.suffix == ".csv":
        return atomic_write_text(path, rows_to_csv(rows))
    raise DataError("unsupported results file; expected .jsonl or .csv", path=path)


def column(rows: Sequence[Mapping[str, Any]], name: str) -> np.ndarray:
    """One numeric column as float64, NaN where missing (schema columns, or any column the rows carry)."""
    extra = name not in COLUMN_BY_NAME and any(isinstance(r.get(name), (int, float)) for r in rows)
    if not extra and (name not in COLUMN_BY_NAME or COLUMN_BY_NAME[name].kind is str):
        raise KeyError(f"{name!r} is not a numeric column; numeric columns: {', '.join(NUMERIC_COLUMNS)}")
    return np.array([np.nan if r.get(name) is None else float(r[name]) for r in rows], dtype=np.float64)


def config_label(row: Mapping[str, Any]) -> str:
    """A short display label: the row's ``label`` or its axes, e.g. ``L8 d384 H6 5%``."""
    if row.get("label"):
        return str(row["label"])
    if row.get("family") == GROUND_TRUTH:
        return "GT"
    parts = []
    for key, prefix in (("layers", "L"), ("dim", "d"), ("heads", "H"), ("codebook", "K")):
        if row.get(key) is not None:
            parts.append(f"{prefix}{row[key]}")
    if not parts and row.get("params") is not None:
        parts.append(f"{row['params'] / 1e6:.2f}M")
    if row.get("data_fraction") is not None and row["data_fraction"] < 1:
        parts.append(f"{100 * row['data_fraction']:g}%")
    return " ".join(parts) or str(row["run_id"])


# ----------------------------------------------------------------------------------------------
# Run folders

_CONFIG_KEYS = ("run_id", "family", "label", "layers", "dim", "heads", "ff", "codebook", "data_fraction",
                "params", "params_non_embedding", "flops_per_sample", "text_flops_per_sample",
                "flops_per_sample_paper", "text_flops_per_sample_paper", "data_sampling", "device_kind", "git_commit")
_LOGGED_LAST = ("steps", "samples_seen", "train_flops")
_LOGGED_STATIC = ("params", "params_non_embedding", "flops_per_sample", "text_flops_per_sample",
                  "flops_per_sample_paper", "text_flops_per_sample_paper")


def _read_json_object(path: Path) -> dict[str, Any]:
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise DataError(f"not valid JSON ({e.msg}, line {e.lineno})", path=path) from None
    if not isinstance(obj, dict):
        raise DataError(f"expected a JSON object, got {type(obj).__name__}", path=path)
    return obj


def _config_values(config: Mapping[str, Any], path: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    scopes = [("", config)]
    for sub in ("model", "data"):
        if isinstance(config.get(sub), Mapping):
            scopes.append((f"{sub}.", config[sub]))
    for key in _CONFIG_KEYS:
        found = [(prefix, scope[key]) for prefix, scope in scopes if scope.get(key) is not None]
        if not found:
            continue
        values = {json.dumps(v, sort_keys=True) for _, v in found}
        if len(values) > 1:
            where = ", ".join(f"{p}{key}={v!r}" for p, v in found)
            raise DataError(f"conflicting values: {where}", path=path, field=key)
        out[key] = found[0][1]
    return out


def _eval_values(ev: Mapping[str, Any], path: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, val in ev.items():
        if key.startswith("_"):
            continue
        base = key[:-3] if key.endswith("_ci") else key
        if base not in METRICS:
            raise DataError(f"unknown metric; known metrics: {', '.join(METRICS)}", path=path, field=key)
        if key.endswith("_ci"):
            out[key] = val
        elif isinstance(val, (list, tuple)):
            if len(val) != 2:
                raise DataError("expected [mean, ci]", path=path, field=key)
            out[key], out[f"{key}_ci"] = val
        elif isinstance(val, Mapping):
            extra = set(val) - {"mean", "ci"}
            if "mean" not in val or extra:
                raise DataError('expected {"mean": x, "ci": y} or a number', path=path, field=key)
            out[key] = val["mean"]
            if val.get("ci") is not None:
                out[f"{key}_ci"] = val["ci"]
        else:
            out[key] = val
    return out


def _find_key(obj: Any, key: str) -> Any:
    """The first value of ``key`` anywhere in nested dicts (eval.json's ``_meta``), else None."""
    if isinstance(obj, Mapping):
        if key in obj:
            return obj[key]
        for v in obj.values():
            found = _find_key(v, key)
            if found is not None:
                return found
    return None


def row_from_run_dir(run_dir: str | os.PathLike) -> dict[str, Any]:
    """Turn a training run folder (see the module docstring) into one validated results row."""
    run_dir = Path(run_dir)
    cfg_path, log_path, eval_path = run_dir / "config.json", run_dir / "metrics.jsonl", run_dir / "eval.json"
    if not cfg_path.exists():
        raise DataError("run folder has no config.json", path=run_dir)
    config = _read_json_object(cfg_path)
    values = _config_values(config, cfg_path)
    seed = config.get("train", {}).get("seed") if isinstance(config.get("train"), Mapping) else None
    if isinstance(seed, int) and not isinstance(seed, bool):
        values["seed"] = seed
    values.setdefault("run_id", run_dir.name)
    if "family" not in values:
        raise DataError("required key is missing", path=cfg_path, field="family")

    if not log_path.exists():
        raise DataError("run folder has no metrics.jsonl", path=run_dir)
    logged = read_jsonl(log_path, strict=False)
    for i, line in enumerate(logged):
        step = line.get("step") if isinstance(line, dict) else None
        if isinstance(step, bool) or not isinstance(step, int):
            raise DataError(f"line {i + 1} has no integer 'step'", path=log_path, field="step")
    logged = sorted(logged, key=lambda d: d["step"])
    if logged:
        values["steps"] = logged[-1]["step"]
    for key in _LOGGED_LAST[1:]:
        for line in reversed(logged):
            if line.get(key) is not None:
                values[key] = line[key]
                break
    for key in _LOGGED_STATIC:
        if key in values:
            continue
        for line in logged:
            if line.get(key) is not None:
                values[key] = line[key]
                break
    if values.get("train_flops") is None and values.get("flops_per_sample") and values.get("samples_seen"):
        values["train_flops"] = 3.0 * float(values["flops_per_sample"]) * float(values["samples_seen"])

    if eval_path.exists():
        ev = _read_json_object(eval_path)
        values.update(_eval_values(ev, eval_path))
        block = _find_key(ev.get("_meta"), "rprec_block")
        if isinstance(block, int) and not isinstance(block, bool):
            values["rprec_block"] = block
        meta = ev.get("_meta") if isinstance(ev.get("_meta"), dict) else {}
        if isinstance(meta.get("evaluator_id"), str):
            values["evaluator_id"] = meta["evaluator_id"]
            values["evaluator"] = meta.get("evaluator_name") or meta["evaluator_id"]
    return Row(validate_row(values, path=run_dir, row=values["run_id"]), source=f"run folder {run_dir}",
               cells=values, file=os.fspath(run_dir))
