"""Plots write non-empty PNG and SVG files."""

import numpy as np
import pytest

from analysis import fits, paper, plots
from analysis.schema import make_row


@pytest.fixture(scope="module")
def table_b():
    return paper.load_table("B")


def _ours():
    rng = np.random.default_rng(0)
    x = np.geomspace(2e9, 3e10, 5)
    return [make_row(run_id=f"tiny-{i}", family="diffusion", layers=2 + 2 * i, dim=64, flops_per_sample=float(v),
                     rprec_top3=float(0.4 * np.log10(v) - 3.6 + rng.normal(0, 0.02)), rprec_top3_ci=0.05)
            for i, v in enumerate(x)]


def _check(path, kind):
    data = path.read_bytes()
    assert len(data) > 5_000
    if kind == "png":
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
    else:
        assert b"<svg" in data[:2000]


@pytest.mark.parametrize("kind", ["png", "svg"])
def test_scaling_plot_with_overlay(tmp_path, table_b, kind):
    fig = plots.plot_scaling(table_b, overlay={"ours": _ours()}, n_boot=200, title="t")
    _check(plots.save_figure(fig, tmp_path / f"s.{kind}"), kind)


def test_other_plots(tmp_path, table_b):
    ext = fits.extrapolate(table_b, 1e10, n_boot=200)
    _check(plots.save_figure(plots.plot_extrapolation(ext, table_b), tmp_path / "e.png"), "png")
    _check(plots.save_figure(plots.plot_axis_grid(paper.load_table("2")), tmp_path / "g.svg"), "svg")
    _check(plots.save_figure(plots.plot_heatmap(paper.load_table("3"), "fid"), tmp_path / "h.png"), "png")
    with pytest.raises(ValueError, match="unsupported figure format"):
        plots.save_figure(plots.plot_heatmap(paper.load_table("3")), tmp_path / "h.jpg")


def _chance_lines(fig):
    return [ln for ax in fig.axes for ln in ax.get_lines() if str(ln.get_label()).startswith("chance")]


def test_plots_draw_the_chance_level(table_b):
    # Table B scores R-Precision in blocks of 16: chance top-3 = 3/16; our rows default to block 32.
    (line,) = _chance_lines(plots.plot_scaling(table_b, n_boot=100))
    assert line.get_label() == "chance (3/16 = 0.188)" and line.get_ydata()[0] == pytest.approx(3 / 16)
    (line,) = _chance_lines(plots.plot_scaling(_ours(), y="rprec_top3", n_boot=100))
    assert line.get_ydata()[0] == pytest.approx(3 / 32)
    assert plots.chance_level("rprec_top1", [], block=32) == pytest.approx(1 / 32)
    assert plots.chance_level("fid") is None
    grid = plots.plot_axis_grid(paper.load_table("2"), ["rprec_top3", "fid"])
    assert [ln.get_ydata()[0] for ln in _chance_lines(grid)] == pytest.approx([3 / 32, 3 / 32])


def test_point_labels_do_not_cover_each_other():
    """Runs of nearly the same compute and score (the CPU study's L2-d128 20% and L2-d64 100%) get labels
    that do not overlap, and a lone point keeps its label to the right of the marker."""
    rows = [make_row(run_id=f"r{i}", family="diffusion", layers=L, dim=d, heads=4, data_fraction=f, train_flops=x,
                     rprec_top3=y, rprec_top3_ci=0.02)
            for i, (L, d, f, x, y) in enumerate([(1, 32, 0.2, 2.8e11, 0.140), (2, 128, 0.2, 5.1e12, 0.194),
                                                  (2, 64, 1.0, 7.6e12, 0.195), (2, 64, 1.0, 8.0e12, 0.196),
                                                  (2, 128, 1.0, 2.6e13, 0.221)])]
    fig = plots.plot_scaling(rows, x="train_flops", y="rprec_top3", n_boot=50)
    ax = fig.axes[0]
    r = fig.canvas.get_renderer()
    labels = [t for t in ax.texts if t.get_gid() == "point-label"]
    boxes = [t.get_window_extent(r) for t in labels]
    assert len(boxes) == 5
    assert not any(boxes[i].overlaps(boxes[j]) for i in range(5) for j in range(i))
    frame = ax.get_window_extent(r)
    assert all(frame.x0 <= b.x0 and b.x1 <= frame.x1 for b in boxes[1:4])  # moved ones stay inside the axes
    assert labels[0].xyann == (6, 0) and labels[0].get_horizontalalignment() == "left"  # nothing near it
    assert {t.xyann for t in labels[1:4]} != {(6, 0)}  # the crowded ones moved


def test_fit_and_plot_any_table_with_the_named_columns(tmp_path, capsys):
    """An analyst's own numbers: columns outside the results schema, no family or run_id columns."""
    import json

    from handx_jax.cli import main

    rng = np.random.default_rng(1)
    x = np.geomspace(1e8, 1e11, 6)
    lines = ["model,my_gflops,top3,notes"] + [f"m{i},{v:.6g},{0.1 * np.log10(v) - 0.5 + rng.normal(0, 0.005):.5f},"
                                              f"run {i}" for i, v in enumerate(x)]
    csv = tmp_path / "mine.csv"
    csv.write_text("\n".join(lines) + "\n")
    assert main(["analyze", "fit", str(csv), "--x", "my_gflops", "--y", "top3", "--json", "--n-boot", "100"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["n"] == 6 and d["slope"] == pytest.approx(0.1, abs=0.01) and d["flops_convention"] is None
    jl = tmp_path / "mine.jsonl"
    jl.write_text("".join(json.dumps({"x": float(v), "rprec_top3": 0.05 * np.log10(v)}) + "\n" for v in x))
    assert main(["analyze", "plot", str(jl), "--x", "x", "--y", "rprec_top3", "--out", str(tmp_path / "p.png")]) == 0
    _check(tmp_path / "p.png", "png")
    # Launcher tables keep the schema check: the table command refuses an unknown column.
    with pytest.raises(SystemExit, match="unknown column"):
        main(["analyze", "table", str(csv)])
