"""Fits: the classical intervals, parameter recovery, CI and prediction-interval coverage, model comparison,
extrapolation."""

import math

import numpy as np
import pytest

from analysis import fits, selection
from analysis.schema import make_row

# Student-t and normal quantiles from standard tables (Abramowitz & Stegun Table 26.10 / 26.1), used
# to check the classical intervals independently of the quantile function the code calls.
T975 = {5: 2.57058184, 10: 2.22813885}
Z975 = 1.959963985


@pytest.mark.parametrize("n", [7, 12])
def test_classical_intervals_match_textbook_formulas(n):
    """method="t": slope CI, prediction interval and Fisher-z CI of r, recomputed by hand from the
    textbook OLS formulas with tabled quantiles (Table B has n = 7)."""
    rng = np.random.default_rng(n)
    x = np.geomspace(1e9, 1e11, n)
    y = 0.44 * np.log10(x) - 3.9 + rng.normal(0.0, 0.03, n)
    f = fits.fit_log_linear(x, y, method="t")
    u = np.log10(x)
    du = u - u.mean()
    a = (du @ (y - y.mean())) / (du @ du)
    b = y.mean() - a * u.mean()
    s = math.sqrt(np.sum((y - a * u - b) ** 2) / (n - 2))
    t = T975[n - 2]
    assert f.slope == pytest.approx(a, rel=1e-12)
    assert f.slope_ci == pytest.approx((a - t * s / math.sqrt(du @ du), a + t * s / math.sqrt(du @ du)), rel=1e-7)
    u0 = 11.5  # x = 10^11.5, beyond the data
    half = t * s * math.sqrt(1 + 1 / n + (u0 - u.mean()) ** 2 / (du @ du))
    lo, hi = f.prediction_interval(10 ** u0)
    assert (float(lo), float(hi)) == pytest.approx((a * u0 + b - half, a * u0 + b + half), rel=1e-7)
    r = np.corrcoef(u, y)[0, 1]
    zq = Z975 / math.sqrt(n - 3)
    assert f.r_ci == pytest.approx((math.tanh(math.atanh(r) - zq), math.tanh(math.atanh(r) + zq)), rel=1e-8)


def test_three_points_have_no_r_interval_and_still_give_json():
    """Fisher's z needs n ≥ 4: with three runs (make demo's mini sweep) the interval is said to be
    undefined, not printed as [nan, nan], and the JSON stays valid (no NaN)."""
    import json

    f = fits.fit_log_linear([1e9, 1e10, 1e11], [0.2, 0.25, 0.33], n_boot=50)
    assert "r = 0.9" in f.summary() and "its CI needs n ≥ 4" in f.summary() and "nan" not in f.summary()
    d = json.loads(json.dumps(f.to_dict(full=True), allow_nan=False))
    assert d["r_ci"] is None and d["n"] == 3


def _synthetic(n, rng, a=0.4, b=-3.5, sigma=0.03):
    x = np.geomspace(1e9, 1e11, n)
    return x, a * np.log10(x) + b + rng.normal(0.0, sigma, n)


def test_fit_recovers_parameters_within_ci():
    rng = np.random.default_rng(0)
    x, y = _synthetic(40, rng)
    f = fits.fit_log_linear(x, y, n_boot=1000)
    assert f.slope_ci[0] <= 0.4 <= f.slope_ci[1]
    assert f.intercept_ci[0] <= -3.5 <= f.intercept_ci[1]
    assert f.slope == pytest.approx(0.4, abs=0.03)
    assert f.r > 0.95 and f.n == 40
    # Noise-free data: exact recovery, r = 1.
    g = fits.fit_log_linear(x, 0.4 * np.log10(x) - 3.5, method="t")
    assert (g.slope, g.intercept) == pytest.approx((0.4, -3.5), abs=1e-10)


def _binomial_ok(hits, n, p):
    """Observed rate within 3 binomial standard deviations of the nominal one."""
    return abs(hits / n - p) <= 3 * math.sqrt(p * (1 - p) / n)


@pytest.mark.parametrize("method", ["bootstrap-t", "t"])
def test_ci_coverage_is_nominal(method):
    # 200 simulated sweeps the size of the paper's Table B (7 runs).
    rng = np.random.default_rng(123)
    sims, cover_a, cover_b = 200, 0, 0
    for s in range(sims):
        x, y = _synthetic(7, rng)
        f = fits.fit_log_linear(x, y, n_boot=500, seed=s, method=method)
        cover_a += f.slope_ci[0] <= 0.4 <= f.slope_ci[1]
        cover_b += f.intercept_ci[0] <= -3.5 <= f.intercept_ci[1]
    assert _binomial_ok(cover_a, sims, 0.95), cover_a / sims
    assert _binomial_ok(cover_b, sims, 0.95), cover_b / sims


def test_prediction_interval_coverage():
    rng = np.random.default_rng(7)
    sims, hits = 400, 0
    for _ in range(sims):
        x, y = _synthetic(8, rng)
        f = fits.fit_log_linear(x, y, method="t")
        x_new = 10 ** rng.uniform(9, 11.3)  # inside and a little past the fitted range
        y_new = 0.4 * math.log10(x_new) - 3.5 + rng.normal(0, 0.03)
        lo, hi = f.prediction_interval(x_new)
        hits += lo <= y_new <= hi
    assert _binomial_ok(hits, sims, 0.95), hits / sims


def test_bootstrap_is_seeded_and_band_nests():
    rng = np.random.default_rng(1)
    x, y = _synthetic(9, rng)
    f1 = fits.fit_log_linear(x, y, seed=5, n_boot=300)
    f2 = fits.fit_log_linear(x, y, seed=5, n_boot=300)
    assert f1.slope_ci == f2.slope_ci
    lo_c, hi_c = f1.confidence_band(x)
    lo_p, hi_p = f1.prediction_interval(x)
    assert np.all(lo_p < lo_c) and np.all(hi_c < hi_p)


def test_fit_rejects_bad_input():
    with pytest.raises(ValueError, match="at least 3"):
        fits.fit_log_linear([1, 2], [1, 2])
    with pytest.raises(ValueError, match="> 0"):
        fits.fit_log_linear([1, 0, 3], [1, 2, 3])
    with pytest.raises(ValueError, match="all x are equal"):
        fits.fit_log_linear([2, 2, 2], [1, 2, 3])


def test_saturating_fit_recovers_curve_and_wins_loo():
    x = np.geomspace(1e8, 1e12, 12)
    y_true = 0.8 - 0.5 * (x / 1e10) ** -0.3
    rng = np.random.default_rng(3)
    y = y_true + rng.normal(0, 0.004, x.size)
    sat = fits.fit_saturating(x, y)
    assert np.max(np.abs(sat.predict(x) - y_true)) < 0.01
    assert sat.alpha == pytest.approx(0.3, abs=0.05)
    assert sat.c == pytest.approx(0.8, abs=0.03)
    cmp = fits.compare_models(x, y)
    assert cmp.best == "saturating"
    # On truly log-linear data the simpler law should not lose by much (and usually wins).
    xl, yl = _synthetic(12, rng)
    cmp2 = fits.compare_models(xl, yl)
    assert cmp2.loo_rmse["log_linear"] <= 1.2 * cmp2.loo_rmse["saturating"]


def _rows(x, y):
    return [make_row(run_id=f"r{i}", family="diffusion", flops_per_sample=float(a), rprec_top3=float(b))
            for i, (a, b) in enumerate(zip(x, y))]


def test_extrapolation_on_synthetic_data():
    rng = np.random.default_rng(11)
    x = np.geomspace(1e9, 1e11, 10)
    y = 0.4 * np.log10(x) - 3.5 + rng.normal(0, 0.02, x.size)
    ext = fits.extrapolate(_rows(x, y), cut=2e10, n_boot=200)
    assert ext.fit.n == int((x < 2e10).sum()) and len(ext.points) == int((x >= 2e10).sum())
    assert all(p.x >= 2e10 for p in ext.points)
    assert ext.rmse < 0.08
    for p in ext.points:
        assert p.pi_low < p.predicted < p.pi_high
    d = ext.to_dict()
    assert d["n_fit"] + d["n_test"] == 10 and 0 <= d["coverage"] <= 1
    # A saturating truth: the log-linear law fitted on small runs over-predicts large ones.
    ys = 0.8 - 0.5 * (x / 1e9) ** -0.8
    ext2 = fits.extrapolate(_rows(x, ys), cut=1e10, n_boot=200)
    assert all(p.predicted > p.actual for p in ext2.points)
    with pytest.raises(ValueError, match="no runs at or above"):
        fits.extrapolate(_rows(x, y), cut=1e12)


def test_select_xy_aliases_and_errors():
    rows = _rows([1e9, 2e9, 4e9], [0.1, 0.2, 0.3]) + [make_row(run_id="gt", family="ground_truth", rprec_top3=0.9)]
    xs, ys, used = selection.select_xy(rows, "flops", "rprec_top3")
    assert xs.tolist() == [1e9, 2e9, 4e9] and len(used) == 3
    with pytest.raises(ValueError, match="unknown column"):
        selection.select_xy(rows, "flop", "rprec_top3")
