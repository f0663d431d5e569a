"""Replicates: runs of one configuration that differ only in their training seed.

A single training run is one draw: on the CPU study, two seeds of the same six configurations gave
top-3 R-Precision up to 0.04 apart and fits with r 0.87 and 0.46 (docs/results/cpu_study). Fitting the
mean over seeds of each configuration is the usual remedy; :func:`mean_replicates` groups rows by every
column that defines a configuration (:func:`config_columns`) and returns one row per group whose metrics
are the means over its replicates, each with a Student-t 95% half-width over the replicates as its
``<metric>_ci`` (none for a single run, whose own ``_ci`` is kept).
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
from scipy.stats import t as student_t

from analysis.schema import METRICS
from handx_jax.families import family_axes


def config_columns() -> tuple[str, ...]:
    """What makes two rows the same configuration (seed, run id, wall time and provenance do not): the shared
    axes, each registered family's own (``Family.axes``: the AR codebook), and what was trained and scored."""
    return ("family", "layers", "dim", "heads", "ff", *family_axes(), "data_fraction", "data_sampling", "steps",
            "samples_seen", "flops_per_sample", "rprec_block", "evaluator_id")


def mean_replicates(rows: Sequence[Mapping[str, Any]], level: float = 0.95) -> list[dict[str, Any]]:
    """One row per configuration, metrics averaged over its replicates (in first-seen order).

    Each output row keeps the first replicate's configuration columns, has ``replicates`` (the count)
    and ``replicate_run_ids``, and, for every metric some replicate has, the mean over the replicates
    that have it with ``<metric>_ci`` = t(level, n−1) · sd / √n (n ≥ 2)."""
    groups: dict[tuple, list[Mapping[str, Any]]] = {}
    keys = config_columns()
    for r in rows:
        groups.setdefault(tuple(r.get(c) for c in keys), []).append(r)
    out = []
    for members in groups.values():
        first = dict(members[0])
        if len(members) == 1:
            out.append({**first, "replicates": 1, "replicate_run_ids": [str(first.get("run_id"))]})
            continue
        row = {k: v for k, v in first.items() if k not in METRICS and not (k.endswith("_ci") and k[:-3] in METRICS)}
        row.pop("seed", None)
        row.pop("wall_time_s", None)
        ids = [str(m.get("run_id")) for m in members]
        row["run_id"] = f"{ids[0]}+{len(ids) - 1}"
        row.update(replicates=len(members), replicate_run_ids=ids)
        for m in METRICS:
            vals = np.array([float(x[m]) for x in members if x.get(m) is not None])
            if vals.size == 0:
                continue
            row[m] = float(vals.mean())
            if vals.size >= 2:
                q = float(student_t.ppf(0.5 + level / 2, vals.size - 1))
                row[f"{m}_ci"] = q * float(vals.std(ddof=1)) / np.sqrt(vals.size)
        out.append(row)
    return out


def describe(before: int, after: Sequence[Mapping[str, Any]]) -> str:
    counts = [int(r.get("replicates", 1)) for r in after]
    return (f"{before} rows -> {len(after)} configurations, mean over replicates "
            f"({', '.join(str(c) for c in counts)} runs each)")
