"""The paper's own numbers: Fig. 4 reproduced, tables bolded as in the paper, and the CLI."""

import argparse
import json

import pytest

from analysis import cli, paper, tables
from analysis.schema import GROUND_TRUTH


def run_cli(argv, capsys):
    p = argparse.ArgumentParser(prog="handx")
    cli.add_parser(p.add_subparsers())
    args = p.parse_args(argv)
    rc = args.func(args)
    return rc, capsys.readouterr().out


def test_fig4_reproduced_to_printed_precision():
    f = paper.fig4_fit()
    assert round(f.slope, 4) == 0.4391
    assert round(f.intercept, 4) == -3.8707
    assert round(f.r, 2) == 0.96
    assert f.n == 7 and paper.fig4_matches(f)
    assert f.slope_ci[0] < f.slope < f.slope_ci[1]


def test_analyze_paper_command(capsys, tmp_path):
    rc, out = run_cli(["analyze", "paper", "--json", "--n-boot", "300"], capsys)
    d = json.loads(out)
    assert rc == 0 and d["fig4"]["matches"] is True
    assert round(d["fig4"]["slope"], 4) == 0.4391 and round(d["fig4"]["intercept"], 4) == -3.8707
    assert round(d["fig4"]["r"], 2) == 0.96
    rc, out = run_cli(["analyze", "paper", "--n-boot", "300", "--plot", str(tmp_path / "fig4.png")], capsys)
    assert "reproduced" in out and (tmp_path / "fig4.png").stat().st_size > 10_000


def test_paper_tables_load():
    t2, t3, tb = paper.load_table("2"), paper.load_table("3"), paper.load_table("tableB")
    assert len(t2) == 11 and len(t3) == 18 and len(tb) == 7
    assert t2[0]["family"] == GROUND_TRUTH and t3[0]["family"] == GROUND_TRUTH
    assert [r["flops_per_sample_paper"] for r in tb] == pytest.approx(
        [g * 1e9 for g in (3.83, 4.22, 5.22, 6.98, 9.74, 12.87, 24.62)], rel=1e-15)
    assert {r["data_fraction"] for r in tb} == {0.05}
    with pytest.raises(ValueError):
        paper.load_table("7")


def _find(rows, **kv):
    (i,) = [i for i, r in enumerate(rows) if all(r.get(k) == v for k, v in kv.items())]
    return i


def test_best_cells_match_the_papers_bold_marks():
    # Bold marks that survive in the paper text (Table 2 and its duplicate Table 4), see
    # analysis/paper_data/README.md.
    rows = paper.load_table("2")
    expected = {
        "rprec_top1": dict(data_fraction=1.0, layers=12),
        "rprec_top2": dict(data_fraction=1.0, layers=12),
        "rprec_top3": dict(data_fraction=1.0, layers=12),
        "fid": dict(data_fraction=0.2, layers=12),  # lower is better
        "mm_dist": dict(data_fraction=0.05, layers=12),  # lower is better
        "contact_precision_intra": dict(data_fraction=0.2, layers=8),
        "contact_recall_intra": dict(data_fraction=1.0, layers=12),
        "contact_f1_intra": dict(data_fraction=1.0, layers=12),
    }
    for metric, where in expected.items():
        assert tables.best_rows(rows, metric) == {_find(rows, **where)}, metric
    # Diversity: closest to GT's 6.887 is 6.903 (0.2, 4 layers).
    assert tables.best_rows(rows, "diversity") == {_find(rows, data_fraction=0.2, layers=4)}
    # Without a GT row, Diversity has no best.
    assert tables.best_rows(rows[1:], "diversity") == set()


def test_render_formats_bold_the_right_cells():
    rows = paper.load_table("2")
    md = tables.render_table(rows, "md")
    lines = md.splitlines()
    assert lines[0].startswith("| Data ratio | Layers | Top-1")
    assert "**0.427 ± 0.079**" in md and "**1.140 ± 0.055**" in md and "**5.331 ± 0.165**" in md
    assert "**6.903 ± 0.064**" in md and md.count("**") == 2 * 9
    assert lines[2].startswith("| Ground Truth")
    tex = tables.render_table(rows, "latex", layout="table2")
    assert r"$\mathbf{0.427}^{\pm \mathbf{0.079}}$" in tex and r"$2.574^{\pm 0.109}$" in tex
    assert tex.count(r"\mathbf") == 2 * 9 and r"\toprule" in tex
    csv_text = tables.render_table(rows, "csv")
    by_id = {line.split(",")[0]: line.split(",")[-1] for line in csv_text.splitlines()[1:]}
    assert by_id["paper-table2-f1.0-L12"] == "rprec_top1;rprec_top2;rprec_top3;contact_recall_intra;contact_f1_intra"
    assert by_id["paper-table2-gt"] == ""


def test_ties_are_all_bold():
    rows = [dict(run_id=str(i), family="diffusion", fid=v) for i, v in enumerate([1.2344, 1.2341, 1.5])]
    assert tables.best_rows(rows, "fid") == {0, 1}


def test_cli_fit_table_extrapolate(capsys, tmp_path):
    rc, out = run_cli(["analyze", "fit", "paper:B", "--x", "flops", "--y", "rprec_top3", "--json",
                       "--n-boot", "200"], capsys)
    d = json.loads(out)
    assert list(d) == ["slope", "intercept", "r", "n", "slope_ci", "intercept_ci", "x_column", "flops_convention"]
    # --x flops on Table B uses the paper's convention (every row has it) and says so.
    assert d["x_column"] == "flops_per_sample_paper" and d["flops_convention"].startswith("paper convention")
    rc, out_a = run_cli(["analyze", "fit", "paper:B", "--x", "flops_analytic", "--json", "--n-boot", "200"], capsys)
    assert json.loads(out_a)["flops_convention"].startswith("analytic")
    assert round(d["slope"], 4) == 0.4391 and d["n"] == 7 and len(d["slope_ci"]) == 2
    # The same from the CSV file itself.
    rc, out2 = run_cli(["analyze", "fit", str(paper.table_path("B")), "--json", "--n-boot", "200"], capsys)
    assert json.loads(out2) == d
    rc, out = run_cli(["analyze", "table", "paper:3", "--format", "md"], capsys)
    assert "| Params (M) | Codebook |" in out and "**0.593**" in out
    rc, out = run_cli(["analyze", "extrapolate", "paper:B", "--cut", "10G", "--json", "--n-boot", "200"], capsys)
    d = json.loads(out)
    assert d["n_fit"] == 5 and d["n_test"] == 2 and d["cut"] == 1e10
    with pytest.raises(SystemExit, match="unknown column 'nope'"):
        run_cli(["analyze", "fit", "paper:B", "--y", "nope"], capsys)
    with pytest.raises(SystemExit, match="no such file"):
        run_cli(["analyze", "fit", str(tmp_path / "missing.jsonl")], capsys)
    out_png = tmp_path / "heat.png"
    run_cli(["analyze", "plot", "paper:3", "--kind", "heatmap", "--out", str(out_png)], capsys)
    assert out_png.stat().st_size > 10_000


def test_cli_fit_refuses_two_evaluators(capsys, tmp_path):
    """Rows scored by different evaluators are on different yardsticks: fit refuses them, names both."""
    rows = [dict(run_id=f"r{i}", family="diffusion", flops_per_sample=10.0 ** (8 + i), rprec_top3=0.1 + 0.05 * i,
                 evaluator="standard-v3" if i < 3 else "9f0e1d2c3b4a5968", evaluator_id="a" * 16 if i < 3 else
                 "9f0e1d2c3b4a5968") for i in range(5)]
    path = tmp_path / "mixed.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(SystemExit, match=r"scored by 2 different evaluators \(9f0e1d2c3b4a5968: r3, r4; "
                                         r"standard-v3 \(aaaaaaaaaaaaaaaa\): r0, r1, r2\)"):
        run_cli(["analyze", "fit", str(path), "--x", "flops_analytic", "--json", "--n-boot", "50"], capsys)
    rc, out = run_cli(["analyze", "fit", str(path), "--x", "flops_analytic", "--json", "--n-boot", "50",
                       "--mixed-evaluators"], capsys)
    assert rc == 0 and json.loads(out)["slope"] == pytest.approx(0.05)
    rows[3]["rprec_top3"] = rows[4]["rprec_top3"] = None  # only one yardstick among the scored rows: fine
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    rc, out = run_cli(["analyze", "fit", str(path), "--x", "flops_analytic", "--json", "--n-boot", "50"], capsys)
    assert json.loads(out)["n"] == 3


def test_cli_help_at_every_level(capsys):
    for argv in (["analyze", "--help"], ["analyze", "paper", "--help"], ["analyze", "fit", "--help"],
                 ["analyze", "table", "--help"], ["analyze", "extrapolate", "--help"],
                 ["analyze", "plot", "--help"], ["analyze", "factors", "--help"], ["analyze", "fig4", "--help"]):
        with pytest.raises(SystemExit) as e:
            run_cli(argv, capsys)
        assert e.value.code == 0
    assert cli.parse_amount("10G") == 1e10 and cli.parse_amount("2.5e9") == 2.5e9


def test_a_reader_that_leaves_early_gets_no_traceback():
    """`handx analyze paper | head -1`: the closed pipe ends the command quietly (exit 141, as a shell's
    SIGPIPE), not with a BrokenPipeError traceback."""
    import subprocess
    import sys

    # `true` reads nothing and is gone long before the fit (a second) has printed anything.
    p = subprocess.run(f"{sys.executable} -m handx_jax analyze paper --n-boot 50 | true; exit ${{PIPESTATUS[0]}}",
                       shell=True, executable="/bin/bash", capture_output=True, text=True)
    assert p.returncode == 141 and p.stderr == "", p.stderr
