"""Bad input to ``handx analyze`` (issue 31 items 3, 5, 6): an analyst's own table fits through its own
columns, an empty table is refused in one line, every row a fit leaves out is named (file, row, column,
why), and plots keep probabilities on [0, 1] with the legend off the points and the chance line drawn.
In-process (``handx_jax.cli.main``), a few hundred bootstrap draws at most: well under a second each."""

import json

import numpy as np
import pytest

from analysis import fits, paper, plots, selection
from analysis.schema import load_results
from handx_jax.cli import main

TABLE_B_HEADER = "flops,rprec_top1,rprec_top2,rprec_top3"


def _table_b_csv(path, nan_row=None, zero_row=None):
    """Table B's seven rows as a plain analyst's CSV: FLOPs as the paper prints them (G × 1e9, the
    convention of the Fig. 4 fit, analysis/paper_data/README.md), top-1/2/3, no schema columns."""
    lines = [TABLE_B_HEADER]
    for i, r in enumerate(paper.load_table("B")):
        top3 = "nan" if i == nan_row else repr(r["rprec_top3"])
        flops = "0" if i == zero_row else repr(r["flops_per_sample_paper"])
        lines.append(f"{flops},{r['rprec_top1']!r},{r['rprec_top2']!r},{top3}")
    path.write_text("\n".join(lines) + "\n")
    return path


def _fail(argv, capsys):
    """Run ``handx ARGV`` expecting a one-line refusal; returns the message."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    msg = str(e.value.code)
    assert e.value.code not in (0, None) and "\n" not in msg and "Traceback" not in msg
    return msg


def test_plain_table_b_csv_fits_through_its_own_flops_column(tmp_path, capsys):
    csv = _table_b_csv(tmp_path / "t.csv")
    assert main(["analyze", "fit", str(csv), "--x", "flops", "--y", "rprec_top3", "--json", "--n-boot", "50"]) == 0
    out = json.loads(capsys.readouterr().out)
    # The paper's Fig. 4: Rprec@3 = 0.4391·log10(FLOPs) − 3.8707, r = 0.96 (Sec. 6.3).
    assert out["x_column"] == "flops" and out["n"] == 7
    assert round(out["slope"], 4) == 0.4391 and round(out["intercept"], 4) == -3.8707 and round(out["r"], 3) == 0.960
    # The alias still means the schema's FLOPs column in a table that has no column of that name.
    assert selection.resolve_column("flops", paper.load_table("B")) == "flops_per_sample_paper"


SCHEMA_HEADER = "run_id,family,flops_per_sample,rprec_top3"


@pytest.mark.parametrize("content", ["", SCHEMA_HEADER + "\n", "# a comment\n" + SCHEMA_HEADER + "\n\n"])
@pytest.mark.parametrize("command", [["fit"], ["table"], ["plot", "--out", "P.png"], ["factors"]])
def test_empty_or_header_only_table_is_refused_in_one_line(tmp_path, capsys, content, command):
    f = tmp_path / "t.csv"
    f.write_text(content)
    argv = ["analyze", command[0], str(f), *[a.replace("P.png", str(tmp_path / "p.png")) for a in command[1:]]]
    msg = _fail(argv, capsys)
    assert f"handx analyze {command[0]}: error: file {f}" in msg and "has no rows" in msg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]  # no blank plot, no table


def test_every_left_out_row_is_named_with_file_row_column_and_why(tmp_path, capsys):
    csv = _table_b_csv(tmp_path / "t.csv", nan_row=2, zero_row=0)
    # By default a row that cannot be used is an error (a fit never runs quietly on n = 5 of 7) ...
    msg = _fail(["analyze", "fit", str(csv), "--x", "flops", "--json", "--n-boot", "20"], capsys)
    assert "2 row(s) hold values that cannot be used" in msg and "row 1, column 'flops'" in msg and "--drop-bad-rows" in msg
    capsys.readouterr()
    # ... and --drop-bad-rows fits the others, naming each row it leaves out
    assert main(["analyze", "fit", str(csv), "--x", "flops", "--json", "--n-boot", "20", "--drop-bad-rows"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["n"] == 5
    lines = cap.err.strip().splitlines()
    assert lines == [f"handx analyze fit: left out file {csv}, row 1, column 'flops': 0 is not > 0, which log10 needs",
                     f"handx analyze fit: left out file {csv}, row 3, column 'rprec_top3': NaN"]

    # A schema table: a missing column, an empty cell, and zero training compute (train_flops may be 0).
    jl = tmp_path / "r.jsonl"
    rows = [{"run_id": "a", "family": "diffusion", "train_flops": 0.0, "rprec_top3": 0.1},
            {"run_id": "b", "family": "diffusion", "train_flops": 1e12},
            {"run_id": "c", "family": "diffusion", "train_flops": 2e12, "rprec_top3": None},
            {"run_id": "gt", "family": "ground_truth", "rprec_top3": 0.9}]
    rows += [{"run_id": f"r{i}", "family": "diffusion", "train_flops": 10.0 ** (12 + i), "rprec_top3": 0.1 * i}
             for i in (1, 2, 3)]
    jl.write_text("".join(json.dumps(r) + "\n" for r in rows))
    msg = _fail(["analyze", "fit", str(jl), "--x", "compute", "--json", "--n-boot", "20"], capsys)
    assert "1 row(s) hold values" in msg and "row 1 (run 'a')" in msg  # train_flops 0; the unscored b, c are not errors
    capsys.readouterr()
    assert main(["analyze", "fit", str(jl), "--x", "compute", "--json", "--n-boot", "20", "--drop-bad-rows"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["n"] == 3
    assert cap.err.strip().splitlines() == [
        f"handx analyze fit: left out file {jl}, row 1 (run 'a'), column 'train_flops': 0 is not > 0, which log10 needs",
        f"handx analyze fit: left out file {jl}, row 2 (run 'b'), column 'rprec_top3': no such column",
        f"handx analyze fit: left out file {jl}, row 3 (run 'c'), column 'rprec_top3': empty"]  # GT: not a run

    # Too few rows left: one line that says how many and names the first left out.
    msg = _fail(["analyze", "fit", str(jl), "--x", "compute", "--y", "fid", "--drop-bad-rows"], capsys)
    assert "need at least 3 rows with train_flops > 0 and fid, got 0 of 7" in msg and "row 1 (run 'a')" in msg


def test_factors_and_plot_name_their_left_out_rows(tmp_path, capsys):
    csv = tmp_path / "f.csv"
    csv.write_text("run_id,family,flops_per_sample,samples_seen,rprec_top3\n"
                   "a,diffusion,1e9,1000,0.1\nb,diffusion,2e9,4000,0.2\nc,diffusion,4e9,2000,nan\n"
                   "d,diffusion,8e9,8000,0.35\ne,diffusion,1e9,8000,0.2\nf,diffusion,4e9,1000,0.25\n")
    assert _fail(["analyze", "factors", str(csv), "--json"], capsys).endswith("to analyse the others")
    capsys.readouterr()
    assert main(["analyze", "factors", str(csv), "--json", "--drop-bad-rows"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["n"] == 5
    assert cap.err.strip() == f"handx analyze factors: left out file {csv}, row 3 (run 'c'), column 'rprec_top3': NaN"
    assert main(["analyze", "plot", str(csv), "--x", "flops_analytic", "--out", str(tmp_path / "p.png"),
                 "--drop-bad-rows"]) == 0
    assert "left out file" in capsys.readouterr().err and (tmp_path / "p.png").stat().st_size > 5000


def _three_runs_at_chance():
    """The demo's three runs of issue 31: top-3 0.170 / 0.083 / 0.136, a fit whose 95% bands leave [0, 1]."""
    return [{"run_id": f"r{i}", "family": "diffusion", "flops_per_sample": x, "rprec_top3": y, "rprec_block": 32}
            for i, (x, y) in enumerate([(1e9, 0.170), (3e9, 0.083), (1e10, 0.136)])]


def test_scaling_plot_keeps_probabilities_on_0_1_legend_off_the_points_and_chance_drawn():
    rows = _three_runs_at_chance()
    fit = fits.fit_rows(rows, "flops", "rprec_top3", n_boot=50)
    assert fit.prediction_interval(1e9)[0] < -0.3 and fit.prediction_interval(1e9)[1] > 1.0  # the case
    fig = plots.plot_scaling(rows, fit=fit, n_boot=50)
    ax = fig.axes[0]
    fig.canvas.draw()
    lo, hi = ax.get_ylim()
    assert -0.02 <= lo and hi <= 1.02
    for coll in ax.collections:  # the bands, clipped
        ys = np.concatenate([p.vertices[:, 1] for p in coll.get_paths()]) if coll.get_paths() else np.zeros(1)
        if len(ys) > 3:
            assert ys.min() >= 0.0 and ys.max() <= 1.0
    for line in ax.lines:  # PI lines and the fit
        y = np.asarray(line.get_ydata(), float)
        assert y.min() >= 0.0 and y.max() <= 1.0
    assert any(line.get_label().startswith("chance (3/32") for line in ax.lines)
    # The legend sits outside the axes, so it can cover no point.
    r = fig.canvas.get_renderer()
    assert not ax.get_legend().get_window_extent(r).overlaps(ax.get_window_extent(r))


def test_extrapolation_plot_band_stays_on_0_1(tmp_path):
    rows = _three_runs_at_chance() + [{"run_id": "big", "family": "diffusion", "flops_per_sample": 3e10,
                                       "rprec_top3": 0.2, "rprec_block": 32}]
    ext = fits.extrapolate(rows, 2e10, x="flops", n_boot=20)
    fig = plots.plot_extrapolation(ext, rows)
    ax = fig.axes[0]
    fig.canvas.draw()
    assert -0.02 <= ax.get_ylim()[0] and ax.get_ylim()[1] <= 1.02
    r = fig.canvas.get_renderer()
    assert not ax.get_legend().get_window_extent(r).overlaps(ax.get_window_extent(r))


def test_left_out_rows_from_a_loaded_table_keep_their_source(tmp_path):
    jl = tmp_path / "r.jsonl"
    jl.write_text(json.dumps({"run_id": "a", "family": "diffusion", "fid": 1.0}) + "\n")
    rows = load_results(jl)
    (d,) = selection.select_rows(rows, ("flops_per_sample", "fid"))[1]
    assert (d.kind, d.file, d.row, d.run, d.column, d.unscored) == (
        selection.DropKind.NO_COLUMN, str(jl), 1, "a", "flops_per_sample", True)
    assert str(d) == f"file {jl}, row 1 (run 'a'), column 'flops_per_sample': no such column"


def test_dropped_rows_say_their_kind_without_parsing_the_message():
    rows = [{"run_id": "a", "family": "diffusion", "flops_per_sample": 0.0, "fid": 1.0},
            {"run_id": "b", "family": "diffusion", "flops_per_sample": 1e9, "fid": float("inf")},
            {"run_id": "c", "family": "diffusion", "flops_per_sample": 1e9, "fid": "x"},
            {"run_id": "d", "family": "diffusion", "flops_per_sample": 1e9}]
    used, dropped = selection.select_rows(rows, ("flops_per_sample", "fid"), log_axis=("flops_per_sample",))
    assert used == []
    assert [(d.kind, d.row, d.run, d.column, d.unscored) for d in dropped] == [
        (selection.DropKind.NOT_POSITIVE, 1, "a", "flops_per_sample", False),
        (selection.DropKind.NOT_FINITE, 2, "b", "fid", False),
        (selection.DropKind.TEXT, 3, "c", "fid", False),
        (selection.DropKind.NO_VALUE, 4, "d", "fid", True)]
    assert [d.reason for d in dropped] == ["0 is not > 0, which log10 needs", "not finite (inf)",
                                           "not a number ('x')", "no value"]
    assert str(dropped[0]) == "run 'a' (row 1 of the input), column 'flops_per_sample': 0 is not > 0, which log10 needs"


# ``handx analyze table`` (issue 43): a NaN metric is not an unscored one. It stopped nothing and printed
# "–" (as for a run not scored yet), a NaN ``_ci`` silently dropped the ±, and a NaN value with its ``_ci``
# was called "``_ci`` given but value is not" in .csv, .jsonl and run folders alike. Now each stops the
# table in one line naming file, row and column, unless --drop-bad-rows, which leaves the row out and says so.

ROWS = [{"run_id": "a", "family": "diffusion", "rprec_top1": 0.30, "rprec_top1_ci": 0.01},
        {"run_id": "b", "family": "diffusion", "rprec_top1": 0.40, "rprec_top1_ci": 0.02},
        {"run_id": "c", "family": "diffusion"}]  # not scored yet: "–", as before


def _table_file(tmp_path, kind, row_b):
    rows = [ROWS[0], {**ROWS[1], **row_b}, ROWS[2]]
    if kind == "csv":
        cols = ["run_id", "family", "rprec_top1", "rprec_top1_ci"]
        p = tmp_path / "r.csv"
        p.write_text("\n".join([",".join(cols)] + [",".join(str(r.get(c, "")) for c in cols) for r in rows]) + "\n")
        return p, f"file {p}, row 2 (run 'b')"
    if kind == "jsonl":
        p = tmp_path / "r.jsonl"
        p.write_text("".join(json.dumps(r) + "\n" for r in rows))  # json writes NaN as NaN
        return p, f"file {p}, row 2 (run 'b')"
    sweep = tmp_path / "sweep"  # run folders: eval.json holds the NaN
    for r in rows:
        d = sweep / r["run_id"]
        d.mkdir(parents=True)
        (d / "config.json").write_text(json.dumps({"family": "diffusion"}))
        (d / "metrics.jsonl").write_text('{"step": 1, "loss": 1.0}\n')
        ev = {k: v for k, v in r.items() if k.startswith("rprec")}
        if ev:
            (d / "eval.json").write_text(json.dumps(ev))
    return sweep, f"run folder {sweep / 'b'} (run 'b')"


@pytest.mark.parametrize("kind", ["csv", "jsonl", "run folders"])
@pytest.mark.parametrize("row_b, column", [({"rprec_top1": float("nan"), "rprec_top1_ci": ""}, "rprec_top1"),
                                           ({"rprec_top1_ci": float("nan")}, "rprec_top1_ci"),
                                           ({"rprec_top1": float("nan")}, "rprec_top1")])
def test_a_nan_metric_stops_the_table_unless_its_rows_are_dropped(tmp_path, capsys, kind, row_b, column):
    row_b = {k: v for k, v in row_b.items() if v != ""}
    path, where = _table_file(tmp_path, kind, row_b)
    msg = _fail(["analyze", "table", str(path)], capsys)
    assert msg == (f"handx analyze table: error: {where}, column {column!r}: NaN: a value that is there but unusable, "
                   "not an unscored one; fix it, or pass --drop-bad-rows to leave such rows out")
    assert main(["analyze", "table", str(path), "--drop-bad-rows"]) == 0
    out, err = capsys.readouterr()
    assert err == f"handx analyze table: left out {where}, column {column!r}: NaN\n"
    body = [ln for ln in out.splitlines() if ln.startswith("| ")][1:]
    assert len(body) == 2 and "0.300 ± 0.010" in body[0] and body[1].endswith("| – |")  # c: unscored, shown as –
