"""Paper-style results tables (HandX Tables 2, 3, B): mean ± CI, best per column in bold.

Which cell is "best" depends on the metric (the paper's convention):

* higher is better: R-Precision and the contact scores;
* lower is better: FID, MM-Dist, MPJPE (also -RA, -PA) and penetration (:data:`analysis.schema.LOWER_IS_BETTER`);
* Diversity, MultiModality, acceleration and jitter have no direction. The best is the value
  closest to the ground truth's, when the table has a ``ground_truth`` row; without one nothing is
  bolded.

Values are compared as printed (rounded to the table's digits), so displayed ties are all bold.
Ground-truth rows are shown first and are never bold. Output: Markdown, CSV (machine-readable:
mean and CI in separate columns, plus a ``best`` column listing the metrics where the row wins)
and LaTeX (booktabs; bold as ``\\mathbf{0.427}^{\\pm\\mathbf{0.079}}`` like the paper).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from analysis.schema import CLOSEST_TO_GT, GROUND_TRUTH, LOWER_IS_BETTER, METRICS, config_label
from analysis.schema.columns import OBJECT_METRICS

# metric -> (markdown header, LaTeX header, digits)
METRIC_INFO: dict[str, tuple[str, str, int]] = {
    "rprec_top1": ("Top-1 ↑", r"Top-1 $\uparrow$", 3),
    "rprec_top2": ("Top-2 ↑", r"Top-2 $\uparrow$", 3),
    "rprec_top3": ("Top-3 ↑", r"Top-3 $\uparrow$", 3),
    "fid": ("FID ↓", r"FID $\downarrow$", 3),
    "diversity": ("Diversity →", r"Diversity $\rightarrow$", 3),
    "mm_dist": ("MM-Dist ↓", r"MM-Dist $\downarrow$", 3),
    "multimodality": ("MModality →", r"MModality $\rightarrow$", 3),
    "mpjpe": ("MPJPE (mm) ↓", r"MPJPE (mm) $\downarrow$", 2),
    "acceleration": ("Accel. →", r"Accel. $\rightarrow$", 3),
    "jitter": ("Jitter →", r"Jitter $\rightarrow$", 3),
    "contact_precision_intra": ("C_prec intra ↑", r"$C_\mathrm{prec}^\mathrm{intra}$ $\uparrow$", 3),
    "contact_recall_intra": ("C_rec intra ↑", r"$C_\mathrm{rec}^\mathrm{intra}$ $\uparrow$", 3),
    "contact_f1_intra": ("C_F1 intra ↑", r"$C_\mathrm{F1}^\mathrm{intra}$ $\uparrow$", 3),
    "contact_precision_inter": ("C_prec inter ↑", r"$C_\mathrm{prec}^\mathrm{inter}$ $\uparrow$", 3),
    "contact_recall_inter": ("C_rec inter ↑", r"$C_\mathrm{rec}^\mathrm{inter}$ $\uparrow$", 3),
    "contact_f1_inter": ("C_F1 inter ↑", r"$C_\mathrm{F1}^\mathrm{inter}$ $\uparrow$", 3),
    "mpjpe_ra_left": ("RA-L (mm) ↓", r"MPJPE-RA$_L$ (mm) $\downarrow$", 2),
    "mpjpe_ra_right": ("RA-R (mm) ↓", r"MPJPE-RA$_R$ (mm) $\downarrow$", 2),
    "mpjpe_pa_left": ("PA-L (mm) ↓", r"MPJPE-PA$_L$ (mm) $\downarrow$", 2),
    "mpjpe_pa_right": ("PA-R (mm) ↓", r"MPJPE-PA$_R$ (mm) $\downarrow$", 2),
    "apd_left": ("APD-L (mm) ↑", r"APD$_L$ (mm) $\uparrow$", 2),  # G-HTT marks APD ↑
    "apd_right": ("APD-R (mm) ↑", r"APD$_R$ (mm) $\uparrow$", 2),
    "pen_1cm": ("Pen 1cm (%) ↓", r"Pen 1cm (\%) $\downarrow$", 2),
    "pen_depth": ("Pen depth (mm) ↓", r"Pen depth (mm) $\downarrow$", 2),
    "contact_feasibility": ("C_feas ↑", r"$C_\mathrm{feas}$ $\uparrow$", 3),
    # BimArt's hand-object metrics (handx eval objects), as its Tab. 1 and 3 print them.
    "obj_pen_1cm": ("Pen 1cm (%) ↓", r"Pen 1cm (\%) $\downarrow$", 1),
    "obj_pen_5mm": ("Pen 5mm (%) ↓", r"Pen 5mm (\%) $\downarrow$", 1),
    "obj_con": ("Con (%) ↑", r"Con (\%) $\uparrow$", 1),
    "obj_art": ("Art (%) ↑", r"Art (\%) $\uparrow$", 1),
    "obj_part_f1": ("Part F1 ↑", r"Part F1 $\uparrow$", 3),
    "obj_cm_cm": ("CM (cm) ↓", r"CM (cm) $\downarrow$", 2),
    "obj_mul_cm": ("Mul (cm) ↑", r"Mul (cm) $\uparrow$", 2),
    "obj_accel_m_per_frame2": ("Accel (m/f²) →", r"Accel (m/f$^2$) $\rightarrow$", 4),
}
assert set(METRIC_INFO) == set(METRICS) | set(OBJECT_METRICS)
# What a hand-object sweep's table shows by default: BimArt's Tab. 3 columns (Pen 5mm and Accel stay in the CSV).
OBJECT_TABLE = ("obj_pen_1cm", "obj_con", "obj_art", "obj_part_f1", "obj_cm_cm", "obj_mul_cm")

# key column -> (header, formatter)
_KEYS: dict[str, tuple[str, Any]] = {
    "run": ("Run", None),
    "data_fraction": ("Data ratio", lambda v: f"{v:g}"),
    "layers": ("Layers", str),
    "dim": ("d", str),
    "heads": ("H", str),
    "ff": ("FFN", str),
    "params": ("Params (M)", lambda v: f"{v / 1e6:.2f}"),
    "flops_per_sample": ("FLOPs (G)", lambda v: f"{v / 1e9:.2f}"),
    "train_flops": ("Train FLOPs", lambda v: f"{v:.3g}"),
}


def _key(name: str) -> tuple[str, Any]:
    """(header, formatter) of a key column: the shared ones above, or a family's own axis (the registry's
    ``Family.axes``, e.g. the AR codebook)."""
    if name in _KEYS:
        return _KEYS[name]
    from handx_jax.families import family_axes

    return family_axes()[name].header, str


_MAIN = ("rprec_top1", "rprec_top2", "rprec_top3", "fid", "diversity", "mm_dist",
         "contact_precision_intra", "contact_recall_intra", "contact_f1_intra")


@dataclass(frozen=True)
class Layout:
    keys: tuple[str, ...]  # columns that identify a row (see _KEYS)
    metrics: tuple[str, ...]


LAYOUTS: dict[str, Layout] = {
    "table2": Layout(keys=("data_fraction", "layers"), metrics=_MAIN),
    "table3": Layout(keys=("params", "codebook"), metrics=_MAIN),
    "tableB": Layout(keys=("layers", "dim", "heads", "ff", "flops_per_sample"),
                     metrics=("rprec_top1", "rprec_top2", "rprec_top3", "fid")),
}


def auto_layout(rows: Sequence[Mapping[str, Any]]) -> Layout:
    """The layout the registry names for a sweep of one family (the AR family's: Table 3), else the axes
    that vary (Table 2 / B style), else a run label."""
    from handx_jax.families import family_axes, names

    runs = [r for r in rows if r.get("family") != GROUND_TRUTH]
    # Rows scored by handx eval objects (a BimArt sweep's) carry obj_* columns; text rows carry the evaluator's.
    metrics = tuple(m for m in (*METRICS, *OBJECT_TABLE) if any(r.get(m) is not None for r in rows))
    fams = {r.get("family") for r in runs}
    if len(fams) == 1 and next(iter(fams)) in names():
        from handx_jax.families import entry

        table = entry(next(iter(fams))).table
        if table:
            return Layout(keys=LAYOUTS[table].keys, metrics=metrics)
    keys: tuple[str, ...] = ()
    for k in ("data_fraction", "layers", "dim", "heads", "ff", *family_axes(), "params", "flops_per_sample"):
        if len({r.get(k) for r in runs}) < 2:
            continue
        # Architecture columns that the chosen keys already determine (e.g. Table C's dim and params
        # per layer count in Table 2) would only widen the table.
        groups: dict[tuple, set] = {}
        for r in runs:
            groups.setdefault(tuple(r.get(c) for c in keys), set()).add(r.get(k))
        if k in ("dim", "heads", "ff", "params") and keys and all(len(v) == 1 for v in groups.values()):
            continue
        keys += (k,)
    if not keys or len({tuple(r.get(k) for k in keys) for r in runs}) < len(runs):
        keys = ("run",) + keys
    return Layout(keys=keys, metrics=metrics)


def _rounded(v: float | None, digits: int) -> float | None:
    return None if v is None else round(float(v), digits)


def best_rows(rows: Sequence[Mapping[str, Any]], metric: str, digits: int | None = None) -> set[int]:
    """Indices of the rows holding the best ``metric`` value (ties included; GT rows excluded)."""
    digits = METRIC_INFO[metric][2] if digits is None else digits
    cand = {i: _rounded(r.get(metric), digits) for i, r in enumerate(rows)
            if r.get("family") != GROUND_TRUTH and r.get(metric) is not None}
    if not cand:
        return set()
    if metric in CLOSEST_TO_GT:
        gt = next((_rounded(r.get(metric), digits) for r in rows
                   if r.get("family") == GROUND_TRUTH and r.get(metric) is not None), None)
        if gt is None:
            return set()
        score = {i: round(abs(v - gt), digits) for i, v in cand.items()}
        target = min(score.values())
        return {i for i, s in score.items() if s == target}
    target = min(cand.values()) if metric in LOWER_IS_BETTER else max(cand.values())
    return {i for i, v in cand.items() if v == target}


def _key_text(row: Mapping[str, Any], key: str) -> str:
    if key == "run":
        return config_label(row)
    if row.get("family") == GROUND_TRUTH:
        return ""
    v = row.get(key)
    return "–" if v is None else _key(key)[1](v)


def _ordered(rows: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    return [r for r in rows if r.get("family") == GROUND_TRUTH] + \
           [r for r in rows if r.get("family") != GROUND_TRUTH]


def render_table(rows: Sequence[Mapping[str, Any]], fmt: str = "md", layout: str | Layout = "auto",
                 digits: int | None = None, caption: str | None = None) -> str:
    """Render ``rows`` as ``md``, ``csv`` or ``latex`` in a paper layout (``auto``, ``table2``,
    ``table3``, ``tableB`` or a :class:`Layout`)."""
    if isinstance(layout, str):
        if layout != "auto" and layout not in LAYOUTS:
            raise ValueError(f"unknown layout {layout!r}; expected auto or one of {', '.join(LAYOUTS)}")
        layout = auto_layout(rows) if layout == "auto" else LAYOUTS[layout]
    rows = _ordered(rows)
    metrics = [m for m in layout.metrics if any(r.get(m) is not None for r in rows)]
    dig = {m: METRIC_INFO[m][2] if digits is None else digits for m in metrics}
    best = {m: best_rows(rows, m, dig[m]) for m in metrics}
    if fmt == "md":
        return _markdown(rows, layout.keys, metrics, dig, best, caption)
    if fmt == "csv":
        return _csv(rows, layout.keys, metrics, best)
    if fmt == "latex":
        return _latex(rows, layout.keys, metrics, dig, best, caption)
    raise ValueError(f"unknown format {fmt!r}; expected md, csv or latex")


def _key_cells(row: Mapping[str, Any], keys: Sequence[str]) -> list[str]:
    cells = [_key_text(row, k) for k in keys]
    if row.get("family") == GROUND_TRUTH and cells:
        cells[0] = "Ground Truth"
    return cells


def _markdown(rows, keys, metrics, dig, best, caption) -> str:
    header = [_key(k)[0] for k in keys] + [METRIC_INFO[m][0] for m in metrics]
    lines = [] if caption is None else [caption, ""]
    lines.append("| " + " | ".join(header) + " |")
    lines.append("|" + "|".join([":---"] * len(keys) + ["---:"] * len(metrics)) + "|")
    for i, r in enumerate(rows):
        cells = _key_cells(r, keys)
        for m in metrics:
            v, ci = r.get(m), r.get(f"{m}_ci")
            if v is None:
                cells.append("–")
                continue
            text = f"{v:.{dig[m]}f}" + ("" if ci is None else f" ± {ci:.{dig[m]}f}")
            cells.append(f"**{text}**" if i in best[m] else text)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _csv(rows, keys, metrics, best) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    key_cols = [k for k in keys if k != "run"]
    header = ["run_id", "family", *key_cols]
    for m in metrics:
        header += [m, f"{m}_ci"]
    w.writerow(header + ["best"])
    for i, r in enumerate(rows):
        out = [r["run_id"], r["family"], *["" if r.get(k) is None else r[k] for k in key_cols]]
        for m in metrics:
            out += ["" if r.get(m) is None else r[m], "" if r.get(f"{m}_ci") is None else r[f"{m}_ci"]]
        w.writerow(out + [";".join(m for m in metrics if i in best[m])])
    return buf.getvalue()


def _latex_escape(s: str) -> str:
    for a, b in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"), ("#", r"\#"),
                 ("–", "--")):
        s = s.replace(a, b)
    return s


def _latex(rows, keys, metrics, dig, best, caption) -> str:
    header = [_latex_escape(_key(k)[0]) for k in keys] + [METRIC_INFO[m][1] for m in metrics]
    lines = ["% generated by analysis.tables (handx-jax); needs \\usepackage{booktabs}",
             "\\begin{table}[t]", "\\centering", "\\small"]
    if caption:
        lines.append(f"\\caption{{{_latex_escape(caption)}}}")
    lines += [f"\\begin{{tabular}}{{{'l' * len(keys)}{'c' * len(metrics)}}}", "\\toprule",
              " & ".join(header) + " \\\\", "\\midrule"]
    for i, r in enumerate(rows):
        cells = [_latex_escape(c) for c in _key_cells(r, keys)]
        for m in metrics:
            v, ci = r.get(m), r.get(f"{m}_ci")
            if v is None:
                cells.append("--")
                continue
            b = i in best[m]
            mean = f"\\mathbf{{{v:.{dig[m]}f}}}" if b else f"{v:.{dig[m]}f}"
            if ci is None:
                cells.append(f"${mean}$")
            else:
                cis = f"\\mathbf{{{ci:.{dig[m]}f}}}" if b else f"{ci:.{dig[m]}f}"
                cells.append(f"${mean}^{{\\pm {cis}}}$")
        lines.append(" & ".join(cells) + " \\\\")
        if r.get("family") == GROUND_TRUTH and i + 1 < len(rows) and rows[i + 1].get("family") != GROUND_TRUTH:
            lines.append("\\midrule")
    lines += ["\\bottomrule", "\\end{tabular}", "\\end{table}"]
    return "\n".join(lines) + "\n"
