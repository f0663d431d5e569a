"""Per-factor slopes (model FLOPs and samples seen) against the one-axis compute fit.

Known answers come from plain refits in the test (numpy least squares, leave-one-out by dropping each
run and refitting, scipy's F distribution), not from the module's hat-matrix shortcuts."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from analysis import fits
from analysis.factors import fit_factor_arrays, fit_factors
from tests.test_analysis_paper import run_cli

STUDY = Path(__file__).resolve().parents[1] / "docs" / "results" / "cpu_study" / "results.csv"


def _grid(n_sizes=4, n_steps=3):
    """A sizes × training-lengths grid, as a sweep over size × data fraction at fixed epochs gives."""
    f = np.repeat(10.0 ** np.linspace(7, 8.5, n_sizes), n_steps)
    s = np.tile(10.0 ** np.linspace(3.5, 5, n_steps), n_sizes)
    return f, s


def _refit(X, y):
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ beta
    return beta, float(r @ r)


def test_slopes_f_test_and_loo_match_plain_refits():
    f, s = _grid()
    noise = np.random.default_rng(0).normal(0, 0.004, f.size)
    y = 0.1 + 0.02 * np.log10(f) + 0.06 * np.log10(s) + noise
    fit = fit_factor_arrays([f, s], y, names=["flops", "samples"])
    u = np.column_stack([np.ones(f.size), np.log10(f), np.log10(s)])
    beta, rss = _refit(u, y)
    np.testing.assert_allclose([fit.intercept, *fit.slopes], beta, rtol=1e-9, atol=1e-12)
    pooled = np.column_stack([np.ones(f.size), np.log10(f * s)])
    beta_p, rss_p = _refit(pooled, y)
    assert fit.pooled_slope == pytest.approx(beta_p[1], rel=1e-9)
    F = (rss_p - rss) / (rss / (f.size - 3))
    assert fit.f_stat == pytest.approx(F, rel=1e-9)
    assert fit.p_value == pytest.approx(stats.f.sf(F, 1, f.size - 3), rel=1e-9)
    assert fit.p_value < 1e-3  # 0.02 vs 0.06 per decade, noise 0.004: clearly unequal
    # leave-one-out: drop each run, refit, predict it
    loo = [y[i] - u[i] @ _refit(np.delete(u, i, 0), np.delete(y, i))[0] for i in range(f.size)]
    loo_p = [y[i] - pooled[i] @ _refit(np.delete(pooled, i, 0), np.delete(y, i))[0] for i in range(f.size)]
    assert fit.loo_rmse == pytest.approx(np.sqrt(np.mean(np.square(loo))), rel=1e-9)
    assert fit.pooled_loo_rmse == pytest.approx(np.sqrt(np.mean(np.square(loo_p))), rel=1e-9)
    assert fit.loo_rmse < fit.pooled_loo_rmse
    # the t interval holds the true slopes, and is the textbook one
    se = np.sqrt(np.diag(np.linalg.inv(u.T @ u)) * rss / (f.size - 3))
    tq = stats.t.ppf(0.975, f.size - 3)
    for j, true in ((0, 0.02), (1, 0.06)):
        lo, hi = fit.slope_ci[j]
        assert lo < true < hi
        assert (lo, hi) == pytest.approx((beta[j + 1] - tq * se[j + 1], beta[j + 1] + tq * se[j + 1]), rel=1e-9)
    np.testing.assert_allclose(fit.predict([f, s]), u @ beta, rtol=1e-12)


def test_equal_slopes_are_not_rejected():
    """Data from the one-axis law: the F test does not reject it at 5% in 95% of such sweeps."""
    f, s = _grid()
    rejections = 0
    for seed in range(200):
        y = 0.05 * np.log10(f * s) - 0.2 + np.random.default_rng(seed).normal(0, 0.01, f.size)
        rejections += fit_factor_arrays([f, s], y).p_value < 0.05
    assert 0 <= rejections <= 20  # nominal 10 of 200; binomial 99.9% bound ~21


def test_pooled_fit_is_the_compute_fit_on_the_cpu_study():
    """With per-sample FLOPs and samples seen, the one-axis model is ``handx analyze fit --x compute``
    (train_flops = 3 × FLOPs per sample × samples seen)."""
    from analysis.cli import load_inputs

    rows = load_inputs([str(STUDY)], strict=False)
    fit = fit_factors(rows)
    compute = fits.fit_rows(rows, "compute", "rprec_top3", method="t")
    assert fit.factors == ("flops_per_sample", "samples_seen") and fit.n == 6
    assert fit.pooled_slope == pytest.approx(compute.slope, rel=1e-9)
    assert fit.pooled_slope_ci == pytest.approx(compute.slope_ci, rel=1e-9)
    assert fit.pooled_r2 == pytest.approx(compute.r ** 2, rel=1e-9)


def test_cli_json_and_errors(capsys, tmp_path):
    rc, out = run_cli(["analyze", "factors", str(STUDY), "--json"], capsys)
    d = json.loads(out)
    assert rc == 0 and d["n"] == 6 and d["dof"] == 3
    assert list(d["factors"]) == ["flops_per_sample", "samples_seen"]
    assert d["equal_slopes_test"]["df"] == [1, 3] and 0 < d["equal_slopes_test"]["p_value"] < 1
    rc, out = run_cli(["analyze", "factors", str(STUDY)], capsys)
    assert "per decade of samples_seen" in out and "equal slopes" in out
    with pytest.raises(SystemExit, match="do not vary independently"):  # train_flops = 3 · f · s
        run_cli(["analyze", "factors", str(STUDY), "--factors", "compute,flops_analytic,samples"], capsys)
    with pytest.raises(SystemExit, match="at least two factors"):
        run_cli(["analyze", "factors", str(STUDY), "--factors", "params"], capsys)
    rows = [dict(run_id=f"r{i}", family="diffusion", params=10.0 ** (5 + i), rprec_top3=0.1 + 0.01 * i)
            for i in range(5)]
    path = tmp_path / "mine.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(SystemExit, match="no run in these results carries 'samples_seen'"):
        run_cli(["analyze", "factors", str(path), "--factors", "params,samples"], capsys)
    with pytest.raises(ValueError, match="need at least 4 runs for 2 factors"):
        fit_factor_arrays([[1.0, 2.0, 3.0], [2.0, 5.0, 3.0]], [0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="factor x2 must be finite and > 0"):
        fit_factor_arrays([[1.0, 2.0, 3.0, 4.0], [2.0, 0.0, 3.0, 1.0]], [0.1, 0.2, 0.3, 0.4])
