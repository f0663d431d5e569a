"""Results tables on disk: read (``.jsonl``, ``.csv``, a run folder, or a sweep folder whose sub-folders are
run folders) and written atomically.

* ``results.jsonl`` -- one JSON object per line, holding any subset of the columns;
* ``results.csv``   -- a header line with column names, then one line per run; an empty cell is a
  missing value and lines starting with ``#`` are comments.

``load_results(..., strict=False)`` (what ``handx analyze fit/plot/extrapolate`` use) accepts any
table with the columns an analysis names: unknown columns are kept, only schema columns are checked.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from analysis.schema.columns import (Row, cell_error, column_by_name, columns, lenient_row, location, unknown_column,
                                     validate_row)
from analysis.schema.run_folder import row_from_run_dir
from handx_jax.infra.atomic import atomic_write_jsonl, atomic_write_text
from handx_jax.infra.errors import DataError
from handx_jax.infra.readers import read_jsonl


def _load_jsonl(path: Path, strict: bool = True) -> list[dict[str, Any]]:
    raws = read_jsonl(path)
    check = validate_row if strict else lenient_row
    return [Row(check(r, path=path, row=i + 1), source=location(path, i + 1), cells=r if isinstance(r, dict) else None,
                file=os.fspath(path), line=i + 1) for i, r in enumerate(raws)]


def _load_csv(path: Path, strict: bool = True) -> list[dict[str, Any]]:
    text = path.read_text(encoding="utf-8")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        return []
    reader = csv.reader(lines)
    header = [h.strip() for h in next(reader)]
    known = column_by_name()
    for h in header if strict else ():
        if h not in known:
            raise unknown_column(h, path=path, row="header")
    if len(set(header)) != len(header):
        raise cell_error("duplicate column in the CSV header", path=path, row="header")
    rows = []
    for i, cells in enumerate(reader):
        if len(cells) != len(header):
            raise cell_error(f"has {len(cells)} cells but the header has {len(header)}", path=path, row=i + 1)
        raw = dict(zip(header, cells))
        rows.append(Row((validate_row if strict else lenient_row)(raw, path=path, row=i + 1),
                        source=location(path, i + 1), cells=raw, file=os.fspath(path), line=i + 1))
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
    return [c.name for c in columns() if c.required or any(r.get(c.name) is not None for r in rows)]


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

