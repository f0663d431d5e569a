"""Which rows and columns enter a fit or a plot: short column names (``flops``, ``compute``, ``data``) resolved
against a table, and every row left out named with where it is and why (no value, NaN, text, ≤ 0 on a log
axis, no such column), so an analysis never drops a run silently."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from analysis.schema import GROUND_TRUTH, column_by_name, numeric_columns


X_ALIASES: dict[str, str] = {
    "flops": "flops_per_sample",  # or flops_per_sample_paper when every run has it (resolve_column)
    "flops_analytic": "flops_per_sample",
    "flops_paper": "flops_per_sample_paper",
    "compute": "train_flops",
    "train_compute": "train_flops",
    "data": "data_fraction",
    "samples": "samples_seen",
}


FLOPS_CONVENTIONS: dict[str, str] = {
    "flops_per_sample": "analytic convention: 2 FLOPs per multiply-add of every matmul of the trainable model, "
                        "text encoder excluded",
    "flops_per_sample_paper": "paper convention (Table B / Fig. 4): multiply-adds of the Linear layers, as "
                              "fvcore/thop count them, plus the frozen text encoder",
}


def resolve_column(name: str, rows: Sequence[Mapping[str, Any]] | None = None) -> str:
    """Map a short name (``flops``, ``compute``, ``params``, ``data``) to a numeric column.

    ``flops`` means the paper's convention (``flops_per_sample_paper``) when every run in ``rows``
    carries it, so that slopes compare with the paper's 0.4391; otherwise the analytic
    ``flops_per_sample``. ``flops_paper`` / ``flops_analytic`` pick one explicitly. With ``rows``, any
    column the rows carry as numbers is accepted too (an analyst's own table), and a column the rows
    carry under an alias's name (a plain CSV with a ``flops`` column) is that column, not the alias.
    """
    if rows is not None and name in X_ALIASES and any(name in r for r in rows):
        return name  # the table's own column wins over the alias of the same name (an analyst's "flops")
    col = X_ALIASES.get(name, name)
    if name == "flops" and rows is not None:
        runs = [r for r in rows if r.get("family") != GROUND_TRUTH]
        if runs and all(r.get("flops_per_sample_paper") is not None for r in runs):
            col = "flops_per_sample_paper"
    by_name = column_by_name()
    if rows is not None and col not in by_name and any(
            isinstance(r.get(col), (int, float)) and not isinstance(r.get(col), bool) for r in rows):
        return col
    if col not in by_name or by_name[col].kind is str:
        raise ValueError(f"unknown column {name!r}; use one of {', '.join(sorted(X_ALIASES))} or a numeric "
                         f"column: {', '.join(numeric_columns())}")
    return col


class DropKind(str, enum.Enum):
    """Why :func:`select_rows` leaves a row out. The first three mean a run not scored yet (a sweep in
    progress, a failed run): named and skipped. The others are a value that is there but unusable: a
    broken table, which the CLI refuses unless asked to drop such rows (``--drop-bad-rows``)."""

    NO_VALUE = "no value"  # a results record without this column's value
    NO_COLUMN = "no such column"  # the file has no such column
    EMPTY = "empty"  # an empty cell
    NAN = "NaN"
    TEXT = "not a number"  # a cell or value that is not a number (text, a bool)
    NOT_FINITE = "not finite"  # ±inf
    NOT_POSITIVE = "not > 0"  # x ≤ 0 on a log axis


UNSCORED = frozenset({DropKind.NO_VALUE, DropKind.NO_COLUMN, DropKind.EMPTY})


@dataclass(frozen=True)
class Dropped:
    """One row an analysis leaves out: where it is (``file`` and ``row``, or ``source`` for a run folder;
    ``row`` alone is its place in rows given in code), its ``run`` id when the table names one, the
    ``column`` and ``kind`` of the problem and the unusable ``value`` as read."""

    kind: DropKind
    column: str
    value: Any = None
    file: str | None = None
    row: int | None = None
    run: str | None = None
    source: str | None = None

    @property
    def unscored(self) -> bool:
        return self.kind in UNSCORED

    @property
    def reason(self) -> str:
        if self.kind is DropKind.TEXT or self.kind is DropKind.NOT_FINITE:
            return f"{self.kind.value} ({self.value!r})"
        if self.kind is DropKind.NOT_POSITIVE:
            return f"{float(self.value):g} is not > 0, which log10 needs"
        return self.kind.value

    @property
    def where(self) -> str:
        if self.source is None:
            return f"run {self.run!r} (row {self.row} of the input)"
        return self.source + (f" (run {self.run!r})" if self.run is not None else "")

    def __str__(self) -> str:
        return f"{self.where}, column {self.column!r}: {self.reason}"


def _why_missing(row: Mapping[str, Any], col: str) -> tuple[DropKind, Any] | None:
    """Why ``row`` has no usable number in ``col`` and the value as read (None if it has one)."""
    v = row.get(col)
    if v is None:
        cells = getattr(row, "cells", None)  # analysis.schema.Row: the cells as read
        if cells is None:
            return DropKind.NO_VALUE, None
        if col not in cells:
            return DropKind.NO_COLUMN, None
        raw = cells[col]
        if raw is None or (isinstance(raw, str) and raw.strip().lower() in ("", "none", "null")):
            return DropKind.EMPTY, raw
        return (DropKind.NAN, raw) if str(raw).strip().lower() == "nan" or raw != raw else (DropKind.TEXT, raw)
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        return DropKind.TEXT, v
    if not math.isfinite(float(v)):
        return (DropKind.NAN, v) if v != v else (DropKind.NOT_FINITE, v)
    return None


def _dropped(row: Mapping[str, Any], index: int, kind: DropKind, column: str, value: Any) -> Dropped:
    source, cells = getattr(row, "source", None), getattr(row, "cells", None)
    named = source is None or cells is None or "run_id" in cells  # else run_id is made up from the file and row
    return Dropped(kind, column, value, file=getattr(row, "file", None),
                   row=getattr(row, "line", None) if source is not None else index + 1,
                   run=row.get("run_id") if named else None, source=source)


def unusable_values(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> list[Dropped]:
    """A :class:`Dropped` for every cell of ``columns`` (ground-truth rows too) that holds a value which is
    there but unusable (NaN, text, ±inf); a missing or empty cell is an unscored one and is not listed. For
    ``handx analyze table``, where such a cell would otherwise print as the "–" of an unscored row."""
    out = []
    for i, r in enumerate(rows):
        for c in columns:
            why = _why_missing(r, c)
            if why is not None and why[0] not in UNSCORED:
                out.append(_dropped(r, i, why[0], c, why[1]))
    return out


def select_rows(rows: Sequence[Mapping[str, Any]], columns: Sequence[str], *, log_axis: Sequence[str] = ()
                ) -> tuple[list[Mapping[str, Any]], list[Dropped]]:
    """The rows with a finite number in every column of ``columns`` (and > 0 in those of ``log_axis``),
    ground-truth rows excluded, and a :class:`Dropped` for every other row: where it is (file and row, or
    run), which column, and why (missing, NaN, empty, text, or a value log10 cannot take)."""
    used, dropped = [], []
    for i, r in enumerate(rows):
        if r.get("family") == GROUND_TRUTH:
            continue
        why = next(((c, *w) for c in columns if (w := _why_missing(r, c)) is not None), None)
        if why is None:
            why = next(((c, DropKind.NOT_POSITIVE, r[c]) for c in log_axis if not float(r[c]) > 0), None)
        if why is None:
            used.append(r)
        else:
            dropped.append(_dropped(r, i, why[1], why[0], why[2]))
    return used, dropped


def dropped_rows(rows: Sequence[Mapping[str, Any]], x: str, y: str) -> list[Dropped]:
    """Every row a fit of ``y`` against ``x`` leaves out, where it is and why (:func:`select_rows`)."""
    return select_rows(rows, (resolve_column(x, rows), resolve_column(y, rows)),
                       log_axis=(resolve_column(x, rows),))[1]


def select_xy(rows: Sequence[Mapping[str, Any]], x: str, y: str) -> tuple[np.ndarray, np.ndarray, list]:
    """The (x, y) pairs of the rows that have both, with x > 0 (a log axis), ground-truth rows excluded;
    :func:`dropped_rows` says which rows were left out and why."""
    xc, yc = resolve_column(x, rows), resolve_column(y, rows)
    used, _ = select_rows(rows, (xc, yc), log_axis=(xc,))
    xs = np.array([float(r[xc]) for r in used], dtype=np.float64)
    ys = np.array([float(r[yc]) for r in used], dtype=np.float64)
    return xs, ys, used
