"""``handx analyze``: scaling fits, paper tables, plots and extrapolation checks from results files.

Wiring: ``handx_jax/cli.py`` calls :func:`add_parser` with its sub-parsers and then ``args.func(args)``.

RESULTS arguments accept ``.jsonl``/``.csv`` results tables, run folders, sweep folders (whose
sub-folders are run folders) and the paper's own tables as ``paper:2``, ``paper:3`` or ``paper:B``.
Several can be given; they are concatenated (run ids must be unique).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Sequence

from handx_jax.cliargs import deprecated_flag
from handx_jax.infra.errors import DataError

_SUFFIX = {"k": 1e3, "m": 1e6, "g": 1e9, "t": 1e12, "p": 1e15, "e": 1e18}


def parse_amount(text: str) -> float:
    """A positive number, optionally with a K/M/G/T/P/E suffix: ``1e10``, ``10G``, ``9.5g``."""
    s = text.strip()
    mult = 1.0
    if s and s[-1].lower() in _SUFFIX:
        mult, s = _SUFFIX[s[-1].lower()], s[:-1]
    try:
        v = float(s) * mult
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r} (e.g. 1e10 or 10G)") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0: {text!r}")
    return v


def load_inputs(specs: Sequence[str], family: str | None = None, strict: bool = True) -> list[dict[str, Any]]:
    """Load RESULTS arguments (files, run folders, ``paper:B``...) and optionally keep one family.

    ``strict=False`` (fit, plot, extrapolate) accepts any CSV/JSON-lines table with the named
    columns; tables and the launcher keep the full schema check.
    """
    from analysis import paper
    from analysis.schema import GROUND_TRUTH, load_results

    rows: list[dict[str, Any]] = []
    seen: dict[str, str] = {}
    for spec in specs:
        part = (paper.load_table(spec.split(":", 1)[1]) if spec.startswith("paper:")
                else load_results(spec, strict=strict))
        if not part:  # an empty table would give an empty table, a blank plot or "need 3 points, got 0"
            raise DataError("has no rows (the table is empty or has only a header): nothing to analyze", path=spec)
        for r in part:
            if r["run_id"] in seen:
                raise DataError(f"run_id {r['run_id']!r} appears in both {seen[r['run_id']]} and {spec}")
            seen[r["run_id"]] = spec
        rows.extend(part)
    if family is not None:
        rows = [r for r in rows if r["family"] in (family, GROUND_TRUTH)]
    return rows


def _left_out(args: argparse.Namespace, dropped: Sequence[Any]) -> None:
    """Name every row an analysis leaves out (``selection.Dropped``: where, which column, why) on stderr. A run
    with no score yet (a sweep in progress, a failed run) is named and skipped; a score or x that is there
    but unusable (NaN, inf, text, x <= 0 on a log axis) is a broken table, refused (exit 1) unless the
    analyst asks to drop such rows (``--drop-bad-rows``), so a fit never quietly runs on n = 5 of 6."""
    for d in dropped:
        print(f"handx analyze {args.analyze_command}: left out {d}", file=sys.stderr)
    bad = [d for d in dropped if not d.unscored]
    if bad and not getattr(args, "drop_bad_rows", False):
        raise DataError(f"{len(bad)} row(s) hold values that cannot be used (named above; first: {bad[0]}); fix "
                        "them, or pass --drop-bad-rows to analyse the others")


def _emit_json(obj: Any) -> None:
    json.dump(obj, sys.stdout, indent=2)
    sys.stdout.write("\n")


def _guard(fn):
    """Turn bad-input errors into a one-line message and exit status 1 (no traceback)."""

    def run(args: argparse.Namespace) -> int:
        try:
            return fn(args) or 0
        except (DataError, ValueError, KeyError, FileExistsError) as e:
            msg = e.args[0] if isinstance(e, KeyError) and e.args else e
            raise SystemExit(f"handx analyze {args.analyze_command}: error: {msg}") from None

    return run


# ----------------------------------------------------------------------------------------------


def _cmd_paper(args: argparse.Namespace) -> int:
    from analysis import paper
    from analysis.fits import compare_models
    from analysis.selection import select_xy

    rows = paper.load_table("B")
    fits = {y: paper.fig4_fit(y, n_boot=args.n_boot, seed=args.seed, level=args.confidence)
            for y in ("rprec_top1", "rprec_top2", "rprec_top3", "fid")}
    main = fits["rprec_top3"]
    xs, ys, _ = select_xy(rows, "flops", "rprec_top3")
    cmp = compare_models(xs, ys)
    if args.json:
        _emit_json({"fig4": {**main.to_dict(full=True), "paper": paper.FIG4, "matches": paper.fig4_matches(main)},
                    "fits": {y: f.to_dict(full=True) for y, f in fits.items()},
                    "model_comparison": cmp.to_dict()})
    else:
        ok = "reproduced" if paper.fig4_matches(main) else "NOT reproduced"
        print("HandX Fig. 4 (Table B, 5% data, R-Precision block 16; x = FLOPs per sample = G × 1e9)")
        print(f"paper:  Rprec@3 = {paper.FIG4['slope']}·log10(FLOPs) − {abs(paper.FIG4['intercept'])}, "
              f"r = {paper.FIG4['r']}")
        print(f"refit:  {main.equation()}  r = {main.r:.4f}  -> {ok}")
        print()
        print(main.summary())
        for y in ("rprec_top1", "rprec_top2", "fid"):
            f = fits[y]
            print(f"{f.equation()}  r = {f.r:.3f}  slope CI [{f.slope_ci[0]:.4f}, {f.slope_ci[1]:.4f}]")
        print()
        print("top-3: log-linear vs saturating, leave-one-out")
        print(cmp.summary())
    if args.plot:
        from analysis.plots import plot_scaling, save_figure

        fig = plot_scaling(rows, "flops", "rprec_top3", name="HandX Table B (5% data)", fit=main,
                           title="HandX Fig. 4 redrawn: top-3 R-Precision vs FLOPs")
        print(f"wrote {save_figure(fig, args.plot)}", file=sys.stderr)
    return 0


def _one_yardstick(rows: Sequence[dict[str, Any]], y: str) -> None:
    """Refuse to fit one curve through scores of different evaluators (rows whose ``evaluator_id``
    differ): the same motion scores differently under each, so the slope would mix yardsticks."""
    ids: dict[str, list[str]] = {}
    for r in rows:
        if r.get(y) is not None and r.get("evaluator_id"):
            eid, name = str(r["evaluator_id"]), r.get("evaluator")
            ids.setdefault(f"{name} ({eid})" if name and name != eid else eid, []).append(str(r["run_id"]))
    if len(ids) > 1:
        found = "; ".join(f"{k}: {', '.join(v[:3])}{' …' if len(v) > 3 else ''}" for k, v in sorted(ids.items()))
        raise DataError(f"{y} was scored by {len(ids)} different evaluators ({found}); one curve needs one "
                        f"yardstick: rescore the runs with one evaluator (relaunching a sweep with --evaluator E "
                        f"rescores only what E did not score), or pass --mixed-evaluators")


def _replicates(rows: list[dict[str, Any]], args: argparse.Namespace) -> list[dict[str, Any]]:
    """``--mean-replicates``: one row per configuration, metrics averaged over its seeds (analysis/replicates.py)."""
    if not getattr(args, "mean_replicates", False):
        return rows
    from analysis.replicates import describe, mean_replicates

    out = mean_replicates(rows)
    print(describe(len(rows), out), file=sys.stderr)
    return out


def _add_mixed_evaluators(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mixed-evaluators", action="store_true",
                   help="fit even if the rows were scored by different evaluators (refused by default)")


def _add_replicates(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mean-replicates", action="store_true",
                   help="fit the mean over replicates (rows of one configuration that differ only in seed) "
                        "instead of every run; each mean's ± is a t-interval over its seeds")


def _one_block(rows: Sequence[dict[str, Any]], y: str) -> None:
    """Refuse one curve through R-Precision of different blocks: top-k at block 16 and at block 32 are two
    metrics (chance k/16 against k/32), whichever evaluator scored them. No flag overrides this."""
    if not y.startswith("rprec_"):
        return
    blocks: dict[int, list[str]] = {}
    for r in rows:
        if r.get(y) is not None and r.get("rprec_block") is not None:
            blocks.setdefault(int(r["rprec_block"]), []).append(str(r.get("run_id")))
    if len(blocks) > 1:
        found = "; ".join(f"block {b}: {', '.join(v[:3])}{' …' if len(v) > 3 else ''}"
                          for b, v in sorted(blocks.items()))
        raise DataError(f"{y} was scored at {len(blocks)} R-Precision blocks ({found}); they are different "
                        f"metrics: rescore the runs at one block (handx sweep rescore --out OUT --block N)")


def _cmd_fit(args: argparse.Namespace) -> int:
    from analysis.fits import compare_models, fit_rows
    from analysis.selection import FLOPS_CONVENTIONS, dropped_rows, resolve_column, select_xy

    rows = load_inputs(args.results, args.family, strict=False)
    if not args.mixed_evaluators:
        _one_yardstick(rows, args.y)
    _one_block(rows, args.y)
    rows = _replicates(rows, args)
    _left_out(args, dropped_rows(rows, args.x, args.y))
    fit = fit_rows(rows, args.x, args.y, level=args.confidence, n_boot=args.n_boot, seed=args.seed, method=args.method)
    xcol = resolve_column(args.x, rows)
    convention = FLOPS_CONVENTIONS.get(xcol)
    if args.json:
        _emit_json({**fit.to_dict(), "x_column": xcol, "flops_convention": convention})
    else:
        print(f"x = {xcol}" + (f" ({convention})" if convention else ""))
        print(fit.summary())
        xs, ys, _ = select_xy(rows, args.x, args.y)
        if xs.size >= 4:
            print()
            print(compare_models(xs, ys).summary())
    if args.plot:
        from analysis.plots import plot_scaling, save_figure

        fig = plot_scaling(rows, args.x, args.y, fit=fit, name=args.name or "runs", level=args.confidence)
        print(f"wrote {save_figure(fig, args.plot)}", file=sys.stderr)
    return 0


def _cmd_fig4(args: argparse.Namespace) -> int:
    from analysis import paper
    from analysis.fig4 import compare_with_fig4
    from analysis.selection import dropped_rows

    rows = load_inputs(args.results, args.family, strict=False)
    if not args.mixed_evaluators:
        _one_yardstick(rows, "rprec_top3")
    _one_block(rows, "rprec_top3")
    rows = _replicates(rows, args)
    _left_out(args, dropped_rows(rows, "flops_paper", "rprec_top3"))
    cmp = compare_with_fig4(rows, level=args.confidence, n_boot=args.n_boot, seed=args.seed)
    if args.json:
        _emit_json(cmp.to_dict())
    else:
        print(cmp.summary())
    if args.plot:
        from analysis.plots import plot_scaling, save_figure

        block = cmp.blocks[0] if len(cmp.blocks) == 1 else None
        fig = plot_scaling(rows, "flops_paper", "rprec_top3", name=args.name or "runs", fit=cmp.fit,
                           overlay={"HandX Table B (block 16, 5% data)": paper.load_table("B")}, block=block,
                           title="Top-3 R-Precision vs FLOPs (paper convention), against Fig. 4")
        print(f"wrote {save_figure(fig, args.plot)}", file=sys.stderr)
    return 0


def _cmd_factors(args: argparse.Namespace) -> int:
    from analysis.factors import fit_factors
    from analysis.selection import resolve_column, select_rows

    rows = load_inputs(args.results, args.family, strict=False)
    if not args.mixed_evaluators:
        _one_yardstick(rows, args.y)
    _one_block(rows, args.y)
    rows = _replicates(rows, args)
    factors = [f.strip() for f in args.factors.split(",") if f.strip()]
    cols = [resolve_column(f, rows) for f in factors]
    _left_out(args, select_rows(rows, (*cols, resolve_column(args.y, rows)), log_axis=cols)[1])
    fit = fit_factors(rows, factors, args.y, level=args.confidence)
    if args.json:
        _emit_json(fit.to_dict())
    else:
        print(fit.summary())
    return 0


def _same_row(row, dropped) -> bool:
    """Whether ``dropped`` (selection.Dropped) names ``row``: the same file and line, or the same run id."""
    if getattr(row, "file", None) is not None and dropped.file is not None:
        return row.file == dropped.file and getattr(row, "line", None) == dropped.row
    return dropped.run is not None and row.get("run_id") == dropped.run


def _cmd_table(args: argparse.Namespace) -> int:
    from analysis.tables import render_table

    from analysis.selection import unusable_values
    from analysis.schema import METRICS

    rows = load_inputs(args.results, args.family)
    # A NaN (or text, inf) metric or interval is not an unscored cell: shown as "–" it would pass for one. It
    # stops the table, naming the first such cell, unless the analyst drops those rows (and is told which).
    bad = unusable_values(rows, [c for m in METRICS for c in (m, f"{m}_ci")])
    if bad and not args.drop_bad_rows:
        more = f" ({len(bad)} such cells in all)" if len(bad) > 1 else ""
        raise DataError(f"{bad[0]}: a value that is there but unusable, not an unscored one{more}; fix it, or pass "
                        "--drop-bad-rows to leave such rows out")
    if bad:
        for d in bad:
            print(f"handx analyze table: left out {d}", file=sys.stderr)
        gone = {id(rows[i]) for i, r in enumerate(rows) for d in bad if _same_row(r, d)}
        rows = [r for r in rows if id(r) not in gone]
    text = render_table(rows, fmt=args.format, layout=args.layout, digits=args.digits, caption=args.caption)
    if args.out:
        from handx_jax.infra.atomic import atomic_write_text

        print(f"wrote {atomic_write_text(args.out, text)}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def _cmd_extrapolate(args: argparse.Namespace) -> int:
    from analysis.fits import extrapolate
    from analysis.selection import dropped_rows

    rows = load_inputs(args.results, args.family, strict=False)
    _one_block(rows, args.y)
    rows = _replicates(rows, args)
    _left_out(args, dropped_rows(rows, args.x, args.y))
    ext = extrapolate(rows, args.cut, x=args.x, y=args.y, level=args.confidence, n_boot=args.n_boot, seed=args.seed)
    if args.json:
        _emit_json(ext.to_dict())
    else:
        print(ext.summary())
    if args.plot:
        from analysis.plots import plot_extrapolation, save_figure

        print(f"wrote {save_figure(plot_extrapolation(ext, rows), args.plot)}", file=sys.stderr)
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from analysis import plots
    from analysis.selection import resolve_column, select_rows

    rows = load_inputs(args.results, args.family, strict=False)
    if args.kind == "scaling":
        overlay = {spec: load_inputs([spec], args.family, strict=False) for spec in args.overlay or []}
        every = [r for part in (rows, *overlay.values()) for r in part]  # one x column for every series
        for part in (rows, *overlay.values()):
            _left_out(args, select_rows(part, (resolve_column(args.x, every), resolve_column(args.y, every)),
                                        log_axis=(resolve_column(args.x, every),))[1])
        fig = plots.plot_scaling(rows, args.x, args.y, overlay=overlay, name=args.name or "runs")
    elif args.kind == "grid":
        fig = plots.plot_axis_grid(rows, args.metrics.split(","))
    else:
        _left_out(args, select_rows(rows, (args.heat_x, args.heat_y, args.y))[1])
        fig = plots.plot_heatmap(rows, args.y, x=args.heat_x, y=args.heat_y)
    print(f"wrote {plots.save_figure(fig, args.out)}", file=sys.stderr)
    return 0


# ----------------------------------------------------------------------------------------------


def _add_fit_options(p: argparse.ArgumentParser, *, xy: bool = True) -> None:
    if xy:
        p.add_argument("--x", default="flops",
                       help="x column or alias: flops (the paper's convention, flops_per_sample_paper, when every "
                            "run has it, else the analytic flops_per_sample; the output names which), flops_paper, "
                            "flops_analytic, compute (train_flops), params, data (data_fraction), samples "
                            "(samples_seen) (default: flops)")
        p.add_argument("--y", default="rprec_top3", help="metric column (default: rprec_top3)")
    deprecated_flag(p, "--level", p.add_argument("--confidence", type=float, default=0.95,
                                                 help="confidence level of CIs and intervals (default: 0.95)"))
    p.add_argument("--n-boot", type=int, default=2000, help="bootstrap resamples (default: 2000)")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed (default: 0)")


def _add_results(p: argparse.ArgumentParser) -> None:
    from analysis.schema import ROW_KINDS
    from handx_jax.families import entry, names

    # the families whose runs are results rows (a tokenizer is a sweep step, not a point), and the evaluator's
    kinds = [f for f in names() if entry(f).results] + [k for k in ROW_KINDS if k != "ground_truth"]

    p.add_argument("results", nargs="+", metavar="RESULTS",
                   help="results .jsonl/.csv, run folder, sweep folder, or paper:2|paper:3|paper:B")
    p.add_argument("--drop-bad-rows", action="store_true",
                   help="leave out (and name) rows whose metric or x is NaN, not a number, or not > 0 on a log "
                        "axis, instead of refusing the table (rows not scored yet are always left out and named)")
    p.add_argument("--family", choices=kinds, default=None,
                   help="keep only runs of this family (and ground-truth rows)")


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``analyze`` and its sub-commands on the ``handx`` command's sub-parsers."""
    p = subparsers.add_parser(
        "analyze", help="scaling fits, paper tables and plots from results files",
        description="Scaling-law analysis of results tables (see analysis/schema/ for the format). "
                    "RESULTS may be .jsonl/.csv tables, run folders, sweep folders, or paper:2, paper:3, "
                    "paper:B for the HandX paper's own tables.")
    p.set_defaults(func=lambda a: p.print_help() or 0, analyze_command=None)
    sub = p.add_subparsers(dest="analyze_command", metavar="COMMAND")

    q = sub.add_parser("paper", help="redo the paper's Fig. 4 fit from Table B and print/plot it",
                       description="Fit the HandX paper's Table B (top-1/2/3 R-Precision and FID against "
                                   "per-sample FLOPs = G × 1e9) and compare with Fig. 4: "
                                   "0.4391·log10(FLOPs) − 3.8707, r = 0.96.")
    q.add_argument("--json", action="store_true", help="print the fits as JSON")
    q.add_argument("--plot", metavar="PATH", help="write the Fig. 4 redraw (.png, .svg or .pdf)")
    _add_fit_options(q, xy=False)
    q.set_defaults(func=_guard(_cmd_paper))

    q = sub.add_parser("fit", help="fit y = a·log10(x) + b with bootstrap CIs",
                       description="Log-linear fit of a metric against FLOPs, compute, params or data, "
                                   "with bootstrap CIs for slope and intercept, and a leave-one-out "
                                   "comparison with a saturating law y = c − k·x^(−α).")
    _add_results(q)
    _add_fit_options(q)
    q.add_argument("--method", choices=("bootstrap-t", "pairs", "t"), default="bootstrap-t",
                   help="CI method: studentized residual bootstrap (default), case-resampling "
                        "percentile, or the classical t-interval")
    q.add_argument("--json", action="store_true",
                   help="print JSON with keys slope, intercept, r, n, slope_ci, intercept_ci")
    q.add_argument("--plot", metavar="PATH", help="write the scaling plot (.png, .svg or .pdf)")
    q.add_argument("--name", help="legend name of the runs")
    _add_mixed_evaluators(q)
    _add_replicates(q)
    q.set_defaults(func=_guard(_cmd_fit))

    q = sub.add_parser("fig4", help="a FLOPs ladder against the paper's Fig. 4 (slope, CI, extrapolation)",
                       description="Fit top-3 R-Precision against per-sample FLOPs in the paper's convention, as "
                                   "Fig. 4 does, and report the slope next to the paper's 0.4391 (with the CI of "
                                   "a refit of Table B), their difference, and the extrapolation check (fit all "
                                   "but the largest run, predict it). Says where the rows are not scored or "
                                   "sized as Fig. 4 is (R-Precision block 16, 5% data, Table B's 7 sizes).")
    _add_results(q)
    _add_fit_options(q, xy=False)
    q.add_argument("--json", action="store_true", help="print the report as JSON")
    q.add_argument("--plot", metavar="PATH", help="write our runs over the paper's Table B points")
    q.add_argument("--name", help="legend name of the runs")
    _add_mixed_evaluators(q)
    _add_replicates(q)
    q.set_defaults(func=_guard(_cmd_fig4))

    q = sub.add_parser("factors", help="a slope per factor (e.g. model FLOPs and samples seen) vs one axis",
                       description="Fit y = a + Σ_j b_j·log10(x_j) over the runs, one slope per factor, and test "
                                   "it against the one-axis fit on the product of the factors (all b_j equal; "
                                   "with the default factors that is training compute, the --x compute fit): "
                                   "t CIs per slope, R², leave-one-out RMSE of both models and the F test of "
                                   "equal slopes. Says which way of spending compute a sweep rewarded.")
    _add_results(q)
    q.add_argument("--factors", default="flops_analytic,samples",
                   help="comma-separated columns or aliases, two or more (default: flops_analytic,samples: "
                        "per-sample FLOPs and samples seen, whose product is training compute / 3)")
    q.add_argument("--y", default="rprec_top3", help="metric column (default: rprec_top3)")
    deprecated_flag(q, "--level", q.add_argument("--confidence", type=float, default=0.95,
                                                 help="confidence level of the CIs (default: 0.95)"))
    q.add_argument("--json", action="store_true", help="print the fit as JSON")
    _add_mixed_evaluators(q)
    _add_replicates(q)
    q.set_defaults(func=_guard(_cmd_factors))

    q = sub.add_parser("table", help="paper-style table (mean ± CI, best in bold)",
                       description="Render results as a Table 2 / Table 3 style table. Best per column "
                                   "in bold: max, or min for FID/MM-Dist/MPJPE, or closest to the "
                                   "ground-truth row for Diversity/MultiModality.")
    _add_results(q)
    q.add_argument("--format", choices=("md", "csv", "latex"), default="md", help="output format (default: md)")
    q.add_argument("--layout", choices=("auto", "table2", "table3", "tableB"), default="auto",
                   help="row keys and metric columns (default: auto)")
    q.add_argument("--digits", type=int, default=None, help="decimals (default: 3, MPJPE 2)")
    q.add_argument("--caption", help="caption (Markdown/LaTeX)")
    q.add_argument("--out", metavar="PATH", help="write to a file instead of stdout")
    q.set_defaults(func=_guard(_cmd_table))

    q = sub.add_parser("extrapolate", help="fit below a compute cut, predict the runs above it",
                       description="Fit the log-linear law on runs with x < CUT and report prediction vs "
                                   "actual, with prediction intervals, for the runs with x >= CUT.")
    _add_results(q)
    q.add_argument("--cut", type=parse_amount, required=True, metavar="FLOPS",
                   help="the cut on x, e.g. 1e10 or 10G")
    _add_fit_options(q)
    q.add_argument("--json", action="store_true", help="print the report as JSON")
    q.add_argument("--plot", metavar="PATH", help="write the extrapolation plot")
    _add_replicates(q)
    q.set_defaults(func=_guard(_cmd_extrapolate))

    q = sub.add_parser("plot", help="scaling plot, per-axis trend grid or codebook × size heatmap",
                       description="Draw one figure from results: 'scaling' (metric vs x on a log axis with "
                                   "the fit), 'grid' (metrics vs depth and data fraction) or 'heatmap' "
                                   "(metric over codebook × model size).")
    _add_results(q)
    q.add_argument("--kind", choices=("scaling", "grid", "heatmap"), default="scaling")
    q.add_argument("--x", default="flops", help="scaling: x column or alias (default: flops)")
    q.add_argument("--y", default="rprec_top3", help="scaling/heatmap: metric (default: rprec_top3)")
    q.add_argument("--metrics", default="rprec_top3,fid,contact_f1_intra",
                   help="grid: comma-separated metrics (default: rprec_top3,fid,contact_f1_intra)")
    q.add_argument("--heat-x", default="codebook", help="heatmap columns (default: codebook)")
    q.add_argument("--heat-y", default="params", help="heatmap rows (default: params)")
    q.add_argument("--overlay", action="append", metavar="RESULTS",
                   help="scaling: another series to overlay (repeatable), e.g. paper:B")
    q.add_argument("--name", help="scaling: legend name of the main series")
    q.add_argument("--out", required=True, metavar="PATH", help="output figure (.png, .svg or .pdf)")
    q.set_defaults(func=_guard(_cmd_plot))
    return p
