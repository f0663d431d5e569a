"""Paper-quality figures for scaling sweeps (matplotlib, Agg, no pyplot global state).

* :func:`plot_scaling`: a metric against FLOPs (or compute, params, data) on a log x-axis, with
  the log-linear fit, its confidence band, the prediction band, per-run error bars and config
  labels. Other series (e.g. our runs over the paper's) can be overlaid.
* :func:`plot_extrapolation`: the fit below a compute cut and the held-out runs above it, with
  their prediction intervals.
* :func:`plot_axis_grid`: per-axis trends, metric vs depth (one line per data fraction) and
  metric vs data fraction (one line per depth), one column per metric.
* :func:`plot_heatmap`: a codebook × model-size heatmap (the AR sweep, paper Table 3).

Figures are built with :class:`matplotlib.figure.Figure` directly, so nothing touches pyplot's
global state or the process-wide backend. :func:`save_figure` writes PNG, SVG or PDF atomically.
Colours are the Okabe-Ito palette, which is safe for colour-blind readers.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import matplotlib as mpl
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from analysis.fits import Extrapolation, LogLinearFit, chance_level, fit_log_linear
from analysis.schema import GROUND_TRUTH, LOWER_IS_BETTER, METRICS, column, column_by_name, config_label
from analysis.selection import resolve_column, select_xy
from analysis.tables import best_rows
from handx_jax.infra.atomic import atomic_write_bytes

OKABE_ITO = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000", "#F0E442")
MARKERS = ("o", "s", "D", "^", "v", "P", "X", "*")

STYLE: dict[str, Any] = {
    "font.size": 10,
    "axes.titlesize": 11,
    "axes.labelsize": 11,
    "xtick.labelsize": 9,
    "ytick.labelsize": 9,
    "legend.fontsize": 9,
    "legend.frameon": False,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "axes.grid.which": "major",
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "lines.linewidth": 1.8,
    "lines.markersize": 6,
    "errorbar.capsize": 2.5,
    "svg.fonttype": "none",  # keep text editable in the SVG
    "axes.prop_cycle": mpl.cycler(color=OKABE_ITO),
}

LABELS: dict[str, str] = {
    "rprec_top1": "R-Precision (top-1)",
    "rprec_top2": "R-Precision (top-2)",
    "rprec_top3": "R-Precision (top-3)",
    "fid": "FID",
    "diversity": "Diversity",
    "mm_dist": "MM-Dist",
    "multimodality": "MultiModality",
    "mpjpe": "MPJPE (mm)",
    "acceleration": "Acceleration",
    "jitter": "Jitter",
    "contact_precision_intra": "Intra-hand $C_\\mathrm{prec}$",
    "contact_recall_intra": "Intra-hand $C_\\mathrm{rec}$",
    "contact_f1_intra": "Intra-hand $C_\\mathrm{F1}$",
    "contact_precision_inter": "Inter-hand $C_\\mathrm{prec}$",
    "contact_recall_inter": "Inter-hand $C_\\mathrm{rec}$",
    "contact_f1_inter": "Inter-hand $C_\\mathrm{F1}$",
    # Either family's count (selection.FLOPS_CONVENTIONS): the denoiser's, or the LM's over its prefix and motion slots.
    "flops_per_sample": "FLOPs per sample (analytic: 2/MAC, trainable model)",
    "flops_per_sample_paper": "FLOPs per sample (paper convention: MACs + text encoder)",
    "train_flops": "Training compute (FLOPs)",
    "params": "Parameters",
    "params_non_embedding": "Non-embedding parameters",
    "data_fraction": "Training data fraction",
    "samples_seen": "Training samples seen",
    "layers": "Layers",
    "codebook": "Codebook size",
}
DPI = 200


# Metrics that are probabilities: their axes and fit bands stay on [0, 1] (a band from −0.5 to 0.8 on a
# top-3 axis, as a 3-run fit draws, says nothing a reader can use).
PROBABILITIES: frozenset[str] = frozenset(m for m in METRICS if m.startswith(("rprec_", "contact_")))


def _clip_probability(v: np.ndarray, col: str) -> np.ndarray:
    return np.clip(v, 0.0, 1.0) if col in PROBABILITIES else v


def _probability_axis(ax: Any, col: str) -> None:
    """A probability axis shows no value outside [0, 1]."""
    if col in PROBABILITIES:
        lo, hi = ax.get_ylim()
        ax.set_ylim(max(lo, -0.02), min(hi, 1.02))


def label(name: str) -> str:
    return LABELS.get(name, name)


def _new_figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | os.PathLike, *, dpi: int = DPI) -> Path:
    """Write ``fig`` to ``path`` (.png, .svg or .pdf, by suffix) atomically."""
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in ("png", "svg", "pdf"):
        raise ValueError(f"unsupported figure format {path.suffix!r}; use .png, .svg or .pdf")
    buf = io.BytesIO()
    with mpl.rc_context(STYLE):
        fig.savefig(buf, format=fmt, dpi=dpi, metadata={"Software": "handx-jax analysis"} if fmt == "png" else None)
    return atomic_write_bytes(path, buf.getvalue())


def _draw_chance(ax: Any, y: str, rows: Sequence[Mapping[str, Any]], block: int | None) -> None:
    c = chance_level(y, rows, block)
    if c is None:
        return
    b = round(int(y[len("rprec_top"):]) / c)
    ax.axhline(c, color="0.45", lw=1.0, ls=(0, (1, 2)), zorder=1,
               label=f"chance ({y[len('rprec_top'):]}/{b} = {c:.3f})")


def _ci(rows: Sequence[Mapping[str, Any]], y: str) -> np.ndarray | None:
    """The rows' ± values of ``y`` for error bars (None when no row has one)."""
    if not rows or (f"{y}_ci" not in column_by_name() and not any(r.get(f"{y}_ci") is not None for r in rows)):
        return None
    ci = column(rows, f"{y}_ci")
    return None if np.all(np.isnan(ci)) else np.nan_to_num(ci)


def _curve_x(xs: np.ndarray, pad: float = 1.15) -> np.ndarray:
    return np.geomspace(xs.min() / pad, xs.max() * pad, 200)


def _draw_fit(ax: Any, fit: LogLinearFit, xs: np.ndarray, color: str, band: bool, pi: bool,
              name: str | None) -> None:
    xc = _curve_x(xs)
    pct = f"{100 * fit.level:g}%"
    if band:
        lo, hi = (_clip_probability(v, fit.y_name) for v in fit.confidence_band(xc))
        ax.fill_between(xc, lo, hi, color=color, alpha=0.15, linewidth=0,
                        label=f"{pct} CI of the fit" if name is None else None)
    if pi:
        lo, hi = (_clip_probability(v, fit.y_name) for v in fit.prediction_interval(xc))
        ax.plot(xc, lo, color=color, lw=0.9, ls=(0, (4, 3)), alpha=0.8,
                label=f"{pct} prediction interval" if name is None else None)
        ax.plot(xc, hi, color=color, lw=0.9, ls=(0, (4, 3)), alpha=0.8)
    sign = "−" if fit.intercept < 0 else "+"
    eq = f"{fit.slope:.4f}·log$_{{10}}$x {sign} {abs(fit.intercept):.4f}  (r = {fit.r:.3f})"
    ax.plot(xc, fit.predict(xc), color=color, lw=1.8, label=eq if name is None else f"{name}: {eq}")


def _short_labels(texts: Sequence[str]) -> list[str]:
    """Drop the words every label shares (e.g. "5%" on a fixed-data sweep)."""
    words = [t.split() for t in texts]
    common = set.intersection(*(set(w) for w in words)) if len(words) > 2 else set()
    return [" ".join(x for x in w if x not in common) or t for w, t in zip(words, texts)]


_POINT_LABEL = "point-label"
# Where a point's label may go, in order of preference (offset in points, alignment): right of the point,
# left of it, then above or below on either side.
_LABEL_SPOTS = (((6, 0), "left"), ((-6, 0), "right"), ((6, 10), "left"), ((6, -10), "left"),
                ((-6, 10), "right"), ((-6, -10), "right"))


def _label_points(ax: Any, xs: np.ndarray, ys: np.ndarray, texts: Sequence[str], color: str) -> None:
    # To the right of each point, clear of its vertical error bar, on a faint white box so that a
    # neighbour's error bar behind it does not make it unreadable (_declutter_labels moves clashing ones).
    for x, y, t in zip(xs, ys, _short_labels(texts)):
        ax.annotate(t, (x, y), xytext=_LABEL_SPOTS[0][0], textcoords="offset points", ha=_LABEL_SPOTS[0][1],
                    va="center", fontsize=7.5, color=color, zorder=5, gid=_POINT_LABEL,
                    bbox=dict(boxstyle="round,pad=0.1", fc="white", ec="none", alpha=0.75))


def _declutter_labels(ax: Any) -> None:
    """Move each point label that would cover an earlier one to the first free spot of _LABEL_SPOTS inside
    the axes (two runs of similar compute and score otherwise print one label over the other). Run once
    the axes' limits are final: the check is in display space."""
    labels = [t for t in ax.texts if t.get_gid() == _POINT_LABEL]
    if len(labels) < 2:
        return
    renderer = ax.figure.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    placed: list[Any] = []
    for t in labels:
        for offset, ha in _LABEL_SPOTS:
            t.xyann = offset
            t.set_horizontalalignment(ha)
            box = t.get_window_extent(renderer)
            inside = frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
            if inside and not any(box.overlaps(p) for p in placed):
                break
        else:  # nowhere free: keep the default spot
            t.xyann = _LABEL_SPOTS[0][0]
            t.set_horizontalalignment(_LABEL_SPOTS[0][1])
            box = t.get_window_extent(renderer)
        placed.append(box)


_ENG_COLUMNS = ("flops_per_sample", "flops_per_sample_paper", "train_flops", "params", "params_non_embedding", "samples_seen")


def _format_log_x(ax: Any, col: str) -> None:
    """Engineering tick labels (4G, 10G, 20G) for counts; plain numbers for fractions."""
    if col in _ENG_COLUMNS:
        fmt = mpl.ticker.EngFormatter(sep="")
        ax.xaxis.set_major_formatter(fmt)
        lo, hi = ax.get_xlim()
        if hi / lo < 30:  # under ~1.5 decades the decade ticks alone are too sparse
            ax.xaxis.set_minor_locator(mpl.ticker.LogLocator(subs=(2, 3, 4, 5, 7)))
            ax.xaxis.set_minor_formatter(fmt)
            ax.tick_params(axis="x", which="both", labelsize=8.5, length=3.5)
    else:
        ax.xaxis.set_major_formatter(mpl.ticker.FormatStrFormatter("%g"))


def _ordered_legend(ax: Any, **kwargs: Any) -> None:
    """Data series first, then fits and bands; below the axes, so that it never covers a point or its
    label (inside, ``loc="best"`` put it over two of the three points of the demo's fit, issue 31)."""
    handles, labels = ax.get_legend_handles_labels()
    order = sorted(range(len(labels)), key=lambda i: (not isinstance(handles[i], mpl.container.ErrorbarContainer), i))
    kwargs = {"loc": "upper center", "bbox_to_anchor": (0.5, -0.16), "ncols": 2, **kwargs}
    ax.legend([handles[i] for i in order], [labels[i] for i in order], **kwargs)


def plot_scaling(rows: Sequence[Mapping[str, Any]], x: str = "flops", y: str = "rprec_top3", *,
                 name: str = "runs", overlay: Mapping[str, Sequence[Mapping[str, Any]]] | None = None,
                 fit: bool | LogLinearFit = True, band: bool = True, pi: bool = True,
                 label_points: bool = True, title: str | None = None, level: float = 0.95,
                 n_boot: int = 1000, figsize: tuple[float, float] = (6.0, 4.2), chance: bool = True,
                 block: int | None = None) -> Figure:
    """``y`` against ``x`` on a log axis with the log-linear fit, its CI band and labelled points.

    ``x="flops"`` uses one FLOPs convention for every series (the paper's only when all have it).
    R-Precision plots draw the chance level k/block (``chance``).
    """
    series = [(name, rows)] + list((overlay or {}).items())
    every = [r for _, srows in series for r in srows]
    xc, yc = resolve_column(x, every), resolve_column(y, every)
    with mpl.rc_context(STYLE):
        fig = _new_figure(*figsize)
        ax = fig.add_subplot()
        all_x = []
        for k, (sname, srows) in enumerate(series):
            color, marker = OKABE_ITO[k % len(OKABE_ITO)], MARKERS[k % len(MARKERS)]
            xs, ys, used = select_xy(srows, xc, yc)
            if xs.size == 0:
                continue
            all_x.append(xs)
            ci = _ci(used, yc)
            ax.errorbar(xs, ys, yerr=ci, fmt=marker, color=color, mfc=color if k == 0 else "white",
                        mec=color, ecolor=color, elinewidth=0.9, alpha=0.95, zorder=3,
                        label=f"{sname} (n = {xs.size})")
            if label_points:
                _label_points(ax, xs, ys, [config_label(r) for r in used], color)
            f = None
            if isinstance(fit, LogLinearFit) and k == 0:
                f = fit
            elif fit is not False and xs.size >= 3 and np.ptp(xs) > 0:
                f = fit_log_linear(xs, ys, level=level, n_boot=n_boot, x_name=xc, y_name=yc)
            if f is not None:
                _draw_fit(ax, f, xs, color, band and k == 0, pi and k == 0, None if k == 0 else sname)
        if chance:
            _draw_chance(ax, yc, every, block)
        ax.set_xscale("log")
        ax.set_xlabel(label(xc))
        ax.set_ylabel(label(yc))
        if title:
            ax.set_title(title)
        ax.grid(True, which="minor", alpha=0.12)
        if all_x:
            ax.set_xlim(*(_curve_x(np.concatenate(all_x), 1.25)[[0, -1]]))
        _format_log_x(ax, xc)
        _probability_axis(ax, yc)
        _ordered_legend(ax)
        _declutter_labels(ax)
    return fig


def plot_extrapolation(ext: Extrapolation, rows: Sequence[Mapping[str, Any]], *, title: str | None = None,
                       figsize: tuple[float, float] = (6.0, 4.2)) -> Figure:
    """The fit on runs below the cut, extended past it, and the held-out runs with their PIs."""
    xs, ys, used = select_xy(rows, ext.x_name, ext.y_name)
    with mpl.rc_context(STYLE):
        fig = _new_figure(*figsize)
        ax = fig.add_subplot()
        below = xs < ext.cut
        c_fit, c_test = OKABE_ITO[0], OKABE_ITO[1]
        xc = np.geomspace(xs.min() / 1.15, xs.max() * 1.15, 200)
        lo, hi = (_clip_probability(v, ext.y_name) for v in ext.fit.prediction_interval(xc))
        pct = f"{100 * ext.fit.level:g}%"
        ax.fill_between(xc, lo, hi, color=c_fit, alpha=0.12, linewidth=0, label=f"{pct} prediction interval")
        ax.plot(xc, ext.fit.predict(xc), color=c_fit, label=f"fit below cut (n = {ext.fit.n}, r = {ext.fit.r:.3f})")
        ax.errorbar(xs[below], ys[below], yerr=_ci([u for u, b in zip(used, below) if b], ext.y_name),
                    fmt="o", color=c_fit, elinewidth=0.9, zorder=3, label="fitted runs")
        px = np.array([p.x for p in ext.points])
        py = np.array([p.actual for p in ext.points])
        pp = np.array([p.predicted for p in ext.points])
        ax.errorbar(px, pp, yerr=np.vstack([pp - [p.pi_low for p in ext.points], [p.pi_high for p in ext.points] - pp]),
                    fmt="_", ms=12, color=c_fit, elinewidth=1.2, capsize=4, zorder=3, label="prediction ± PI")
        ax.plot(px, py, "D", color=c_test, mfc="white", mew=1.6, zorder=4, label="held-out runs (actual)")
        _label_points(ax, px, py, [p.label for p in ext.points], c_test)
        ax.axvline(ext.cut, color="0.35", lw=1.0, ls=":", zorder=1)
        ax.annotate("cut", (ext.cut, 0.02), xycoords=("data", "axes fraction"), xytext=(3, 0),
                    textcoords="offset points", fontsize=8, color="0.35")
        ax.set_xscale("log")
        ax.set_xlabel(label(ext.x_name))
        ax.set_ylabel(label(ext.y_name))
        cut = mpl.ticker.EngFormatter(sep="")(ext.cut) if ext.x_name in _ENG_COLUMNS else f"{ext.cut:g}"
        ax.set_title(title or f"Extrapolation past {cut}: RMSE {ext.rmse:.3f}, "
                              f"{pct} PI covers {sum(p.inside for p in ext.points)}/{len(ext.points)}")
        ax.grid(True, which="minor", alpha=0.12)
        _format_log_x(ax, ext.x_name)
        _probability_axis(ax, ext.y_name)
        _ordered_legend(ax)
        _declutter_labels(ax)
    return fig


def _trend_panel(ax: Any, rows: Sequence[Mapping[str, Any]], metric: str, x: str, hue: str,
                 logx: bool, hue_fmt: Any, show_gt: bool) -> None:
    runs = [r for r in rows if r.get("family") != GROUND_TRUTH and r.get(metric) is not None
            and r.get(x) is not None]
    hues = sorted({r.get(hue) for r in runs if r.get(hue) is not None})
    for k, h in enumerate(hues):
        sel = sorted((r for r in runs if r.get(hue) == h), key=lambda r: r[x])
        xs = np.array([r[x] for r in sel], dtype=float)
        ys = np.array([r[metric] for r in sel], dtype=float)
        ci = _ci(sel, metric)
        ax.errorbar(xs, ys, yerr=ci, fmt="-" + MARKERS[k % len(MARKERS)], color=OKABE_ITO[k % len(OKABE_ITO)],
                    elinewidth=0.8, label=hue_fmt(h))
    _draw_chance(ax, metric, rows, None)
    gt = next((r[metric] for r in rows if r.get("family") == GROUND_TRUTH and r.get(metric) is not None), None)
    if gt is not None and show_gt:
        ax.axhline(gt, color="0.4", lw=1.0, ls=":", label="ground truth")
    if logx:
        ax.set_xscale("log")
        vals = sorted({r[x] for r in runs})
        ax.set_xticks(vals, [f"{v:g}" for v in vals])
        ax.minorticks_off()
    else:
        vals = sorted({r[x] for r in runs})
        ax.set_xticks(vals)
    ax.set_xlabel(label(x))


def plot_axis_grid(rows: Sequence[Mapping[str, Any]],
                   metrics: Sequence[str] = ("rprec_top3", "fid", "contact_f1_intra"), *,
                   depth: str = "layers", data: str = "data_fraction", title: str | None = None,
                   show_gt: bool = False) -> Figure:
    """Per-axis trends: row 1 = metric vs depth (a line per data fraction), row 2 = vs data fraction.

    ``show_gt`` draws the ground-truth value as a dotted line (it can squeeze the runs' range).
    """
    metrics = [m for m in metrics if any(r.get(m) is not None for r in rows)]
    if not metrics:
        raise ValueError("none of the requested metrics is present in the rows")
    with mpl.rc_context(STYLE):
        fig = _new_figure(3.3 * len(metrics) + 1.4, 6.2)
        axes = fig.subplots(2, len(metrics), squeeze=False)
        for j, m in enumerate(metrics):
            arrow = " (lower is better)" if m in LOWER_IS_BETTER else ""
            _trend_panel(axes[0, j], rows, m, depth, data, logx=False, hue_fmt=lambda h: f"{100 * h:g}% data",
                         show_gt=show_gt)
            _trend_panel(axes[1, j], rows, m, data, depth, logx=True, hue_fmt=lambda h: f"{h} layers",
                         show_gt=show_gt)
            axes[0, j].set_title(label(m) + arrow)
            axes[0, j].set_ylabel(label(m))
            axes[1, j].set_ylabel(label(m))
        for i in range(2):
            seen: dict[str, Any] = {}
            for ax in axes[i]:
                for h, lab in zip(*ax.get_legend_handles_labels()):
                    seen.setdefault(lab, h)
            axes[i, -1].legend(list(seen.values()), list(seen.keys()), loc="center left",
                               bbox_to_anchor=(1.02, 0.5))
        if title:
            fig.suptitle(title)
    return fig


def plot_heatmap(rows: Sequence[Mapping[str, Any]], metric: str = "rprec_top3", *, x: str = "codebook",
                 y: str = "params", title: str | None = None, cmap: str | None = None) -> Figure:
    """``metric`` on a grid of ``x`` (columns) × ``y`` (rows), values printed, best cell outlined."""
    runs = [r for r in rows if r.get("family") != GROUND_TRUTH and r.get(x) is not None
            and r.get(y) is not None and r.get(metric) is not None]
    if not runs:
        raise ValueError(f"no rows have {x}, {y} and {metric}")
    xv = sorted({r[x] for r in runs})
    yv = sorted({r[y] for r in runs})
    grid = np.full((len(yv), len(xv)), np.nan)
    for r in runs:
        grid[yv.index(r[y]), xv.index(r[x])] = r[metric]
    best = {(yv.index(runs[i][y]), xv.index(runs[i][x])) for i in best_rows(runs, metric)}
    cmap = cmap or ("viridis_r" if metric in LOWER_IS_BETTER else "viridis")
    fmt_y = (lambda v: f"{v / 1e6:.2f}M") if y in ("params", "params_non_embedding") else str
    with mpl.rc_context({**STYLE, "axes.grid": False, "axes.spines.top": True, "axes.spines.right": True}):
        fig = _new_figure(1.2 * len(xv) + 2.6, 0.55 * len(yv) + 1.6)
        ax = fig.add_subplot()
        cm = mpl.colormaps[cmap].with_extremes(bad="0.92")
        im = ax.imshow(np.ma.masked_invalid(grid), cmap=cm, aspect="auto", origin="lower")
        finite = grid[np.isfinite(grid)]
        mid = 0.5 * (finite.min() + finite.max())
        for i in range(len(yv)):
            for j in range(len(xv)):
                v = grid[i, j]
                if np.isnan(v):
                    ax.text(j, i, "–", ha="center", va="center", color="0.5", fontsize=9)
                    continue
                # Light text on the dark end of the colour map.
                dark = (v < mid) != (cmap.endswith("_r"))
                ax.text(j, i, f"{v:.3f}", ha="center", va="center", fontsize=9,
                        color="white" if dark else "black", fontweight="bold" if (i, j) in best else "normal")
                if (i, j) in best:
                    ax.add_patch(mpl.patches.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="#D55E00", lw=2.2))
        ax.set_xticks(range(len(xv)), [str(v) for v in xv])
        ax.set_yticks(range(len(yv)), [fmt_y(v) for v in yv])
        ax.set_xlabel(label(x))
        ax.set_ylabel("Model size" if y == "params" else label(y))
        cb = fig.colorbar(im, ax=ax, shrink=0.9)
        cb.set_label(label(metric) + (" (lower is better)" if metric in LOWER_IS_BETTER else ""))
        ax.set_title(title or label(metric))
    return fig
