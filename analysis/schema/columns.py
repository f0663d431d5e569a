"""The results table's columns: what a row holds, their types and checks, and rows built and validated.

A results table is a list of rows; a row is a plain ``dict`` keyed by the column names of
:func:`columns` (every column present, ``None`` where unknown). Unknown columns are an error (a misspelled
metric must not vanish silently), and so are values of the wrong type; :class:`handx_jax.infra.errors.DataError`
names the file, the row and the column.

Columns (see :func:`columns` for the full list and units):

* identity: ``run_id`` (unique across all files loaded together), ``family`` (a registered family,
  ``evaluator`` or ``ground_truth`` -- the latter marks the reference row of a table), ``label``;
* axes: ``layers``, ``dim``, ``heads``, ``ff``, each registered family's own (``Family.axes``: the AR
  family's ``codebook``), ``data_fraction``;
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
"""

from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from handx_jax.families import family_axes, names
from handx_jax.infra.errors import DataError


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
# BimArt §4 hand -> object, scored by ``handx eval objects`` (metrics/objects.py), not by the evaluator: Pen 1cm /
# 5mm (% frames), Con, Art (%), part contact F1 against the ground truth, CM (cm), Mul (cm), Accel (m / frame²).
OBJECT_METRICS: tuple[str, ...] = ("obj_pen_1cm", "obj_pen_5mm", "obj_con", "obj_art", "obj_part_f1", "obj_cm_cm",
                                   "obj_mul_cm", "obj_accel_m_per_frame2")
LOWER_IS_BETTER: frozenset[str] = frozenset({"fid", "mm_dist", "mpjpe", "mpjpe_ra_left", "mpjpe_ra_right",
                                             "mpjpe_pa_left", "mpjpe_pa_right", "pen_1cm", "pen_depth",
                                             "obj_pen_1cm", "obj_pen_5mm", "obj_cm_cm"})
# No direction: the best value is the one closest to the ground truth's (paper Tables 2/3).
# Acceleration or jitter below the data's means over-smoothed motion, not better motion, so the best
# value for them is also the one closest to the ground truth.
CLOSEST_TO_GT: frozenset[str] = frozenset({"diversity", "multimodality", "acceleration", "jitter",
                                           "obj_accel_m_per_frame2"})
GROUND_TRUTH = "ground_truth"
# Rows that are not a model family's runs; the families themselves are the registry's
# (handx_jax.families, a light module: no JAX is imported).
ROW_KINDS: tuple[str, ...] = ("evaluator", GROUND_TRUTH)


def families() -> list[str]:
    """Every value the ``family`` column may take: the registered families, then ``ROW_KINDS``."""
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


# The columns every row has, whatever the registry holds; each family's own axes go after ``ff`` (columns()).
SHARED_COLUMNS: tuple[Column, ...] = (
    Column("run_id", str, "unique id of the run", required=True),
    Column("family", str, "model family (the registry, handx_jax.families) | evaluator | ground_truth",
           required=True),
    Column("label", str, "free-text display label"),
    Column("layers", int, "transformer layers (L)", positive=True),
    Column("dim", int, "model width (d)", positive=True),
    Column("heads", int, "attention heads (H)", positive=True),
    Column("ff", int, "feed-forward width (FFN)", positive=True),
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
    *(c for m in OBJECT_METRICS for c in (
        Column(m, float, f"hand-object metric {m} (handx eval objects)"),
        Column(f"{m}_ci", float, f"half-width of the 95% interval of {m} (a bootstrap over clips)", nonnegative=True))),
    # Provenance of a launcher row (sweeps/launcher.py).
    Column("sweep", str, "sweep name"),
    Column("status", str, "launcher status: done | trained | failed | running | pending"),
    Column("error", str, "why the run failed (launcher rows)"),
    Column("data_sampling", str, "how training items are drawn: clips (nested clip subsets) | pairs"),
    Column("wall_time_s", float, "wall-clock seconds the run's stages took", nonnegative=True),
    Column("device_kind", str, "accelerator the run trained on (jax.devices()[0].device_kind)"),
    Column("git_commit", str, "git commit of the code that trained the run"),
)
_AXES_AFTER = "ff"  # family axes sit here, so a table's column order does not depend on who declared them


def family_columns() -> tuple[Column, ...]:
    """The columns the registered families declare: their sweep axes (``Family.axes``, e.g. the AR family's
    codebook), read from the registry on each call so a family registered later has its columns too."""
    return tuple(Column(a.name, a.kind, f"{a.header}: a sweep axis of a registered family (config key {a.key})",
                        positive=True) for a in family_axes().values())


def columns() -> tuple[Column, ...]:
    """Every column of a results row: the shared ones with the registered families' axes after ``ff``."""
    k = next(i for i, c in enumerate(SHARED_COLUMNS) if c.name == _AXES_AFTER) + 1
    return (*SHARED_COLUMNS[:k], *family_columns(), *SHARED_COLUMNS[k:])


def column_by_name() -> dict[str, Column]:
    return {c.name: c for c in columns()}


def numeric_columns() -> tuple[str, ...]:
    return tuple(c.name for c in columns() if c.kind is not str)


def location(path: Any, row: Any) -> str:
    parts = []
    if path is not None:
        parts.append(f"file {os.fspath(path)}")
    if row is not None:
        parts.append(f"row {row}")
    return ", ".join(parts)


def cell_error(msg: str, *, path: Any = None, row: Any = None, column: str | None = None) -> DataError:
    where = location(path, row)
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
            raise cell_error(f"expected a number, got {value!r}", path=path, row=row, column=col.name) from None
    elif col.kind is str:
        raise cell_error(f"expected a string, got {type(value).__name__} {value!r}", path=path, row=row,
                     column=col.name)
    elif isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise cell_error(f"expected a number, got {type(value).__name__} {value!r}", path=path, row=row,
                     column=col.name)
    else:
        num = float(value)
        if math.isnan(num):
            return None
    if not math.isfinite(num):
        raise cell_error(f"value must be finite, got {value!r}", path=path, row=row, column=col.name)
    if col.kind is int:
        if num != round(num):
            raise cell_error(f"expected an integer, got {value!r}", path=path, row=row, column=col.name)
        out: Any = int(round(num))
    else:
        out = num
    if col.positive and not out > 0:
        raise cell_error(f"must be > 0, got {value!r}", path=path, row=row, column=col.name)
    if col.nonnegative and out < 0:
        raise cell_error(f"must be >= 0, got {value!r}", path=path, row=row, column=col.name)
    return out


def unknown_column(name: str, *, path: Any, row: Any) -> DataError:
    names = [c.name for c in columns()]
    close = difflib.get_close_matches(name, names, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return cell_error(f"unknown column{hint}; known columns: {', '.join(names)}", path=path, row=row,
                  column=name)


def _is_nan(v: Any) -> bool:
    if isinstance(v, str):
        return v.strip().lower() == "nan"
    return isinstance(v, (float, np.floating)) and v != v


def validate_row(raw: Mapping[str, Any], *, path: Any = None, row: Any = None) -> dict[str, Any]:
    """Check one raw row and return it as a full row (every column, None where missing)."""
    if not isinstance(raw, Mapping):
        raise cell_error(f"expected an object, got {type(raw).__name__}", path=path, row=row)
    cols = columns()
    known = {c.name for c in cols}
    unknown = [k for k in raw if k not in known]
    if unknown:
        raise unknown_column(unknown[0], path=path, row=row)
    out = {c.name: _coerce(c, raw.get(c.name), path=path, row=row) for c in cols}
    for c in cols:
        if c.required and out[c.name] is None:
            raise cell_error("required value is missing", path=path, row=row, column=c.name)
    if out["family"] not in families():
        raise cell_error(f"unknown family {out['family']!r}; expected one of {families()}", path=path,
                     row=row, column="family")
    if out["data_fraction"] is not None and out["data_fraction"] > 1:
        raise cell_error(f"must be in (0, 1], got {out['data_fraction']}", path=path, row=row,
                     column="data_fraction")
    for m in METRICS:
        # A NaN value is not a missing one: it is there but unusable, which the analysis that reads the row
        # reports or drops (selection.unusable_values, selection.select_rows), naming the cell.
        if out[f"{m}_ci"] is not None and out[m] is None and not _is_nan(raw.get(m)):
            raise cell_error(f"{m}_ci is given but {m} is not", path=path, row=row, column=f"{m}_ci")
    return out


def lenient_row(raw: Mapping[str, Any], *, path: Any = None, row: Any = None) -> dict[str, Any]:
    """An analyst's row: schema columns are type-checked, other columns kept (numbers parsed).

    For ``handx analyze fit/plot`` on any table with the named columns: no required columns beyond
    what the command uses (``run_id`` defaults to the row number, ``family`` to None = a run).
    """
    if not isinstance(raw, Mapping):
        raise cell_error(f"expected an object, got {type(raw).__name__}", path=path, row=row)
    by_name = column_by_name()
    out: dict[str, Any] = {name: None for name in by_name}
    for k, v in raw.items():
        k = str(k).strip()
        if k in by_name:
            out[k] = _coerce(by_name[k], v, path=path, row=row)
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



def column(rows: Sequence[Mapping[str, Any]], name: str) -> np.ndarray:
    """One numeric column as float64, NaN where missing (schema columns, or any column the rows carry)."""
    by_name = column_by_name()
    extra = name not in by_name and any(isinstance(r.get(name), (int, float)) for r in rows)
    if not extra and (name not in by_name or by_name[name].kind is str):
        raise KeyError(f"{name!r} is not a numeric column; numeric columns: {', '.join(numeric_columns())}")
    return np.array([np.nan if r.get(name) is None else float(r[name]) for r in rows], dtype=np.float64)


def config_label(row: Mapping[str, Any]) -> str:
    """A short display label: the row's ``label`` or its axes, e.g. ``L8 d384 H6 5%``."""
    if row.get("label"):
        return str(row["label"])
    if row.get("family") == GROUND_TRUTH:
        return "GT"
    parts = []
    axes = (("layers", "L"), ("dim", "d"), ("heads", "H"), *((a.name, a.short) for a in family_axes().values()))
    for key, prefix in axes:
        if row.get(key) is not None:
            parts.append(f"{prefix}{row[key]}")
    if not parts and row.get("params") is not None:
        parts.append(f"{row['params'] / 1e6:.2f}M")
    if row.get("data_fraction") is not None and row["data_fraction"] < 1:
        parts.append(f"{100 * row['data_fraction']:g}%")
    return " ".join(parts) or str(row["run_id"])

