"""`handx analyze fig4`: a FLOPs ladder fitted as the paper's Fig. 4 is, next to the paper's slope,
with the extrapolation check and the reasons a comparison is not like for like."""

import json

import numpy as np
import pytest
from scipy.stats import norm

from analysis import paper
from analysis.fig4 import compare_with_fig4
from tests.test_analysis_paper import run_cli


def ladder(slope, *, block=16, fraction=0.05, sizes=7, wiggle=0.01):
    """Rows on a known line in the paper's FLOPs convention, with a fixed ± wiggle (so the fit has a residual)."""
    g = np.geomspace(3.83e9, 24.62e9, sizes)
    y = slope * np.log10(g) - 3.9 + wiggle * np.array([1, -1] * sizes)[:sizes]
    return [dict(run_id=f"r{i}", family="diffusion", layers=2 + i, dim=256, flops_per_sample_paper=float(x),
                 flops_per_sample=float(x) / 2, rprec_top3=float(v), fid=30.0 - i, rprec_block=block, data_fraction=fraction,
                 evaluator="standard-v3", evaluator_id="a" * 16) for i, (x, v) in enumerate(zip(g, y))]


def test_table_b_against_itself_is_the_paper():
    """The paper's own rows: slope 0.4391, difference 0, like for like; the extrapolation check's
    prediction of the largest size equals an independent least-squares fit of the six smaller ones."""
    c = compare_with_fig4(paper.load_table("B"), n_boot=300)
    assert round(c.fit.slope, 4) == 0.4391 and c.slope_difference == pytest.approx(c.fit.slope - 0.4391)
    assert c.comparable and c.caveats == () and c.blocks == (16,) and c.fractions == (0.05,)
    assert c.paper_slope_in_ci
    lo, hi = c.slope_difference_ci()
    assert lo < 0 < hi
    rows = sorted(paper.load_table("B"), key=lambda r: r["flops_per_sample_paper"])
    u = np.log10([r["flops_per_sample_paper"] for r in rows])
    y = np.array([r["rprec_top3"] for r in rows])
    a, b = np.polyfit(u[:6], y[:6], 1)
    (p,) = c.extrapolation.points
    assert c.extrapolation.fit.n == 6 and p.x == rows[-1]["flops_per_sample_paper"]
    assert p.predicted == pytest.approx(a * u[6] + b, abs=1e-12) and p.actual == y[6]
    assert p.inside == (p.pi_low <= y[6] <= p.pi_high)


def test_slope_difference_and_its_interval_from_independent_least_squares():
    rows = ladder(0.2)
    c = compare_with_fig4(rows, n_boot=300)
    u = np.log10([r["flops_per_sample_paper"] for r in rows])
    y = np.array([r["rprec_top3"] for r in rows])
    slope, icpt = np.polyfit(u, y, 1)
    resid = y - (slope * u + icpt)
    se = np.sqrt(resid @ resid / (len(u) - 2) / np.sum((u - u.mean()) ** 2))
    assert c.fit.slope == pytest.approx(slope, abs=1e-12) and c.fit.slope_se == pytest.approx(se, rel=1e-9)
    assert c.slope_difference == pytest.approx(slope - 0.4391, abs=1e-12)
    half = norm.ppf(0.975) * np.hypot(se, paper.fig4_fit(n_boot=50).slope_se)
    assert c.slope_difference_ci() == pytest.approx((slope - 0.4391 - half, slope - 0.4391 + half), abs=1e-12)
    assert not c.paper_slope_in_ci and c.fit.slope_ci[1] < 0.4391  # 0.2 per decade is clearly not 0.4391


def test_caveats_name_what_differs_from_fig4(capsys, tmp_path):
    c = compare_with_fig4(ladder(0.3, block=32, fraction=0.2, sizes=5), n_boot=200)
    assert not c.comparable and len(c.caveats) == 3
    assert "block 32, Fig. 4's is 16" in c.caveats[0] and "--block 16" in c.caveats[0]
    assert "data fraction 0.2, Fig. 4's is 0.05" in c.caveats[1] and "5 model sizes" in c.caveats[2]
    assert "NOT like for like" in c.summary()
    # A short FLOPs range (tiny denoisers behind a large text encoder) is named too.
    short = ladder(0.3)
    for i, r in enumerate(short):
        r["flops_per_sample_paper"] = 3.4e9 * (1 + 0.01 * i)
    (cav,) = compare_with_fig4(short, n_boot=100).caveats
    assert cav.startswith("FLOPs per sample span 1.06x (Table B: 6.43x)")
    # Three runs: a fit, no extrapolation check (it needs three below the largest).
    assert compare_with_fig4(ladder(0.3, sizes=3), n_boot=100).extrapolation is None

    path = tmp_path / "ladder.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in ladder(0.3)))
    rc, out = run_cli(["analyze", "fig4", str(path), "--json", "--n-boot", "200"], capsys)
    d = json.loads(out)
    assert rc == 0 and d["comparable"] and d["paper"]["slope"] == 0.4391 and d["paper"]["block"] == 16
    assert d["fit"]["slope"] == pytest.approx(0.3, abs=0.02) and d["extrapolation"]["n_fit"] == 6
    rc, out = run_cli(["analyze", "fig4", str(path), "--n-boot", "200", "--plot", str(tmp_path / "f.png")], capsys)
    assert "slope is outside our slope's CI" in out and "slopes compare directly" in out
    assert (tmp_path / "f.png").stat().st_size > 10_000


def test_mixed_blocks_and_missing_paper_flops_are_refused(capsys, tmp_path):
    rows = ladder(0.3)
    rows[0]["rprec_block"] = rows[1]["rprec_block"] = 32
    path = tmp_path / "mixed.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    for cmd in (["fig4"], ["fit", "--x", "flops"], ["extrapolate", "--cut", "10G"], ["factors"]):
        with pytest.raises(SystemExit, match=r"scored at 2 R-Precision blocks \(block 16: r2, r3, r4 …; "
                                             r"block 32: r0, r1\); they are different metrics"):
            run_cli(["analyze", cmd[0], str(path), *cmd[1:]], capsys)
    # FID does not depend on the block: fitting it over both is fine.
    rc, out = run_cli(["analyze", "fit", str(path), "--x", "flops", "--y", "fid", "--json", "--n-boot", "50"], capsys)
    assert rc == 0 and json.loads(out)["n"] == 7
    rows = ladder(0.3)
    del rows[2]["flops_per_sample_paper"]
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(SystemExit, match="runs without flops_per_sample_paper .*e.g. r2"):
        run_cli(["analyze", "fig4", str(path)], capsys)
