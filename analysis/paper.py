"""The HandX paper's published numbers (Tables 2, 3, B) and its Fig. 4 fit.

The tables live in ``analysis/paper_data/*.csv`` in the results schema. ``paper_data/README.md``
says where each number came from and which columns were filled in from Table C.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from analysis.fits import LogLinearFit, fit_rows
from analysis.schema import load_results

PAPER_DATA = Path(__file__).resolve().parent / "paper_data"
TABLES = {"2": "table2.csv", "3": "table3.csv", "B": "tableB.csv"}

# Sec. 6.3 / Fig. 4: top-3 R-Precision (block size 16) against per-sample FLOPs in raw units,
# fitted on Table B (paper convention, handx_jax/families/diffusion/flops.py).
FIG4 = {"x": "flops_per_sample_paper", "y": "rprec_top3", "slope": 0.4391, "intercept": -3.8707, "r": 0.96}


def table_path(name: str) -> Path:
    key = str(name).strip().upper()
    key = key[len("TABLE"):].strip() if key.startswith("TABLE") else key
    if key not in TABLES:
        raise ValueError(f"unknown paper table {name!r}; available: {', '.join(TABLES)}")
    return PAPER_DATA / TABLES[key]


def load_table(name: str) -> list[dict[str, Any]]:
    """Rows of the paper's Table ``name`` ("2", "3" or "B"; "table2" etc. also accepted)."""
    return load_results(table_path(name))


def fig4_fit(y: str = "rprec_top3", **kwargs: Any) -> LogLinearFit:
    """Redo the Fig. 4 fit: ``y`` of Table B against per-sample FLOPs (G × 1e9)."""
    return fit_rows(load_table("B"), x=FIG4["x"], y=y, **kwargs)


def fig4_matches(fit: LogLinearFit) -> bool:
    """True if the fit reproduces the printed Fig. 4 numbers to their printed precision."""
    return (round(fit.slope, 4) == FIG4["slope"] and round(fit.intercept, 4) == FIG4["intercept"]
            and round(fit.r, 2) == FIG4["r"])
