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
