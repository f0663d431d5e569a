"""Scaling fits: y = a·log10(x) + b with honest uncertainty, a saturating alternative, extrapolation.

The paper's central result is one such fit (Fig. 4, from Table B): top-3 R-Precision =
0.4391·log10(FLOPs) − 3.8707, r = 0.96. :func:`fit_log_linear` reproduces it and adds what the
paper leaves out:

* bootstrap CIs for a and b. The default is the studentized residual bootstrap ("bootstrap-t",
  Davison & Hinkley 1997, Alg. 6.3 with leverage-adjusted residuals), which keeps close to nominal
  coverage at the sweep sizes we have (7 points in Table B); ``method="pairs"`` gives the plain
  case-resampling percentile interval, which under-covers at such sizes;
* prediction intervals for a new run (the classical OLS t-interval);
* a saturating alternative y = c − k·x^(−α) (:func:`fit_saturating`), compared with the
  log-linear law by leave-one-out error (:func:`compare_models`);
* :func:`extrapolate`: fit on runs below a compute cut, predict the runs above it.

Quantiles come from ``scipy.stats`` (scipy ships with jax; no hand-written special functions).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.stats import norm as normal, t as student_t

from analysis.schema import config_label
from analysis.selection import dropped_rows, resolve_column, select_xy


# ----------------------------------------------------------------------------------------------
# Log-linear fit


@dataclass(frozen=True)
class LogLinearFit:
    """y = slope·log10(x) + intercept, fitted by ordinary least squares."""

    slope: float
    intercept: float
    r: float
    n: int
    slope_ci: tuple[float, float]
    intercept_ci: tuple[float, float]
    level: float
    slope_se: float
    intercept_se: float
    resid_std: float  # s, with n − 2 degrees of freedom
    u_mean: float  # mean of log10(x)
    suu: float  # sum of squared deviations of log10(x)
    r_ci: tuple[float, float]
    method: str
    n_boot: int
    x_name: str = "x"
    y_name: str = "y"

    def predict(self, x: Any) -> np.ndarray:
        return self.slope * np.log10(np.asarray(x, dtype=np.float64)) + self.intercept

    def _band(self, x: Any, level: float | None, new_obs: bool) -> tuple[np.ndarray, np.ndarray]:
        level = self.level if level is None else level
        u = np.log10(np.asarray(x, dtype=np.float64))
        var = 1.0 / self.n + (u - self.u_mean) ** 2 / self.suu + (1.0 if new_obs else 0.0)
        half = float(student_t.ppf(0.5 + level / 2, self.n - 2)) * self.resid_std * np.sqrt(var)
        mid = self.predict(x)
        return mid - half, mid + half

    def prediction_interval(self, x: Any, level: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Interval that holds a *new* run's y at x with probability ``level`` (OLS t-interval)."""
        return self._band(x, level, new_obs=True)

    def confidence_band(self, x: Any, level: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Interval for the fitted *mean* y at x (the band drawn around the fit line)."""
        return self._band(x, level, new_obs=False)

    def to_dict(self, full: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {"slope": self.slope, "intercept": self.intercept, "r": self.r, "n": self.n,
                               "slope_ci": list(self.slope_ci), "intercept_ci": list(self.intercept_ci)}
        if full:
            out.update(level=self.level, slope_se=self.slope_se, intercept_se=self.intercept_se,
                       resid_std=self.resid_std,
                       # None, not NaN, where undefined (n < 4): NaN is not JSON
                       r_ci=list(self.r_ci) if all(math.isfinite(v) for v in self.r_ci) else None,
                       method=self.method,
                       n_boot=self.n_boot, x=self.x_name, y=self.y_name)
        return out

    def equation(self, digits: int = 4) -> str:
        sign = "−" if self.intercept < 0 else "+"
        return f"{self.y_name} = {self.slope:.{digits}f}·log10({self.x_name}) {sign} {abs(self.intercept):.{digits}f}"

    def summary(self) -> str:
        pct = f"{100 * self.level:g}%"
        return "\n".join([
            self.equation(),
            f"  n = {self.n}, r = {self.r:.4f} "
            + (f"({pct} CI [{self.r_ci[0]:.3f}, {self.r_ci[1]:.3f}])" if all(math.isfinite(v) for v in self.r_ci)
               else "(its CI needs n ≥ 4)"),
            f"  slope     {self.slope:.4f} ± {self.slope_se:.4f} (se); {pct} {self.method} CI "
            f"[{self.slope_ci[0]:.4f}, {self.slope_ci[1]:.4f}]",
            f"  intercept {self.intercept:.4f} ± {self.intercept_se:.4f} (se); {pct} {self.method} CI "
            f"[{self.intercept_ci[0]:.4f}, {self.intercept_ci[1]:.4f}]",
            f"  residual std {self.resid_std:.4f}",
        ])


def _check_xy(x: Any, y: Any, min_n: int) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    if x.shape != y.shape:
        raise ValueError(f"x and y differ in length ({x.size} vs {y.size})")
    if x.size < min_n:
        raise ValueError(f"need at least {min_n} points, got {x.size}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("x and y must be finite")
    if np.any(x <= 0):
        raise ValueError("x must be > 0 for a log10 fit")
    if np.ptp(x) == 0:
        raise ValueError("all x are equal; the slope is undefined")
    return x, y


def _ols(u: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    du = u - u.mean()
    slope = float(du @ (y - y.mean()) / (du @ du))
    return slope, float(y.mean() - slope * u.mean())


def fit_log_linear(x: Any, y: Any, *, level: float = 0.95, n_boot: int = 2000, seed: int = 0,
                   method: str = "bootstrap-t", x_name: str = "x", y_name: str = "y") -> LogLinearFit:
    """Fit y = a·log10(x) + b. ``method``: ``bootstrap-t`` (default), ``pairs`` or ``t`` (classical)."""
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    if method not in ("bootstrap-t", "pairs", "t"):
        raise ValueError(f"unknown method {method!r}; expected bootstrap-t, pairs or t")
    x, y = _check_xy(x, y, min_n=3)
    n = x.size
    u = np.log10(x)
    u_mean = float(u.mean())
    du = u - u_mean
    suu = float(du @ du)
    dy = y - y.mean()
    syy = float(dy @ dy)
    slope = float(du @ dy) / suu
    intercept = float(y.mean()) - slope * u_mean
    fitted = slope * u + intercept
    resid = y - fitted
    s = math.sqrt(float(resid @ resid) / (n - 2))
    se_a = s / math.sqrt(suu)
    se_b = s * math.sqrt(1.0 / n + u_mean ** 2 / suu)
    r = float(du @ dy) / math.sqrt(suu * syy) if syy > 0 else float("nan")
    alpha = 1.0 - level

    if n > 3 and abs(r) < 1:
        z, zq = math.atanh(r), float(normal.ppf(1 - alpha / 2)) / math.sqrt(n - 3)
        r_ci = (math.tanh(z - zq), math.tanh(z + zq))  # Fisher z
    else:
        r_ci = (float("nan"), float("nan"))

    if method == "t":
        tq = float(student_t.ppf(1 - alpha / 2, n - 2))
        slope_ci = (slope - tq * se_a, slope + tq * se_a)
        intercept_ci = (intercept - tq * se_b, intercept + tq * se_b)
        n_boot = 0
    else:
        rng = np.random.default_rng(seed)
        idx = rng.integers(0, n, size=(n_boot, n))
        if method == "pairs":
            ub, yb = u[idx], y[idx]
            dub = ub - ub.mean(axis=1, keepdims=True)
            sub = np.einsum("bn,bn->b", dub, dub)
            ok = sub > 1e-12 * suu  # a resample with a single distinct x has no slope
            a_b = np.einsum("bn,bn->b", dub[ok], yb[ok]) / sub[ok]
            b_b = yb[ok].mean(axis=1) - a_b * ub[ok].mean(axis=1)
            q = [alpha / 2, 1 - alpha / 2]
            slope_ci = tuple(float(v) for v in np.quantile(a_b, q))
            intercept_ci = tuple(float(v) for v in np.quantile(b_b, q))
        else:
            # Residual bootstrap with leverage-adjusted, re-centred residuals; the CI inverts the
            # bootstrap distribution of the studentized estimate (a* − a)/se*.
            h = 1.0 / n + du ** 2 / suu
            e = resid / np.sqrt(1.0 - h)
            e = e - e.mean()
            yb = fitted + e[idx]  # (B, n)
            a_b = (yb @ du) / suu
            b_b = yb.mean(axis=1) - a_b * u_mean
            rb = yb - (a_b[:, None] * u + b_b[:, None])
            s_b = np.sqrt(np.einsum("bn,bn->b", rb, rb) / (n - 2))
            ok = s_b > 1e-12 * max(s, 1e-300)
            t_a = (a_b[ok] - slope) / (s_b[ok] / math.sqrt(suu))
            t_b = (b_b[ok] - intercept) / (s_b[ok] * math.sqrt(1.0 / n + u_mean ** 2 / suu))
            qa = np.quantile(t_a, [alpha / 2, 1 - alpha / 2])
            qb = np.quantile(t_b, [alpha / 2, 1 - alpha / 2])
            slope_ci = (slope - float(qa[1]) * se_a, slope - float(qa[0]) * se_a)
            intercept_ci = (intercept - float(qb[1]) * se_b, intercept - float(qb[0]) * se_b)

    return LogLinearFit(slope=slope, intercept=intercept, r=r, n=n, slope_ci=tuple(slope_ci),
                        intercept_ci=tuple(intercept_ci), level=level, slope_se=se_a, intercept_se=se_b,
                        resid_std=s, u_mean=u_mean, suu=suu, r_ci=r_ci, method=method, n_boot=n_boot,
                        x_name=x_name, y_name=y_name)


def fit_rows(rows: Sequence[Mapping[str, Any]], x: str = "flops", y: str = "rprec_top3",
             **kwargs: Any) -> LogLinearFit:
    """Log-linear fit of column ``y`` against column ``x`` over the rows that have both (x > 0)."""
    xs, ys, _ = select_xy(rows, x, y)
    if xs.size < 3:
        xc, yc = resolve_column(x, rows), resolve_column(y, rows)
        dropped = dropped_rows(rows, x, y)
        eg = f"; first left out: {dropped[0]}" if dropped else ""
        raise ValueError(f"need at least 3 rows with {xc} > 0 and {yc}, got {xs.size} of {len(rows)}{eg}")
    return fit_log_linear(xs, ys, x_name=resolve_column(x, rows), y_name=resolve_column(y, rows), **kwargs)


# ----------------------------------------------------------------------------------------------
# Saturating alternative


@dataclass(frozen=True)
class SaturatingFit:
    """y = c − k·(x / x_ref)^(−α), α > 0: approaches the asymptote c as x grows."""

    c: float
    k: float
    alpha: float
    x_ref: float
    sse: float
    n: int

    def predict(self, x: Any) -> np.ndarray:
        return self.c - self.k * (np.asarray(x, dtype=np.float64) / self.x_ref) ** (-self.alpha)

    def equation(self, digits: int = 4) -> str:
        sign = "−" if self.k >= 0 else "+"
        return (f"y = {self.c:.{digits}f} {sign} {abs(self.k):.{digits}f}·(x/{self.x_ref:.3g})^(−{self.alpha:.{digits}f})")


DEFAULT_ALPHAS = np.geomspace(1e-3, 5.0, 400)


def fit_saturating(x: Any, y: Any, alphas: np.ndarray | None = None) -> SaturatingFit:
    """Least squares over (c, k, α): a grid over α, (c, k) solved linearly, then a golden-section polish.

    x is scaled by its geometric mean so the fit is well conditioned for raw FLOPs (~1e10). As α → 0
    the model tends to the log-linear law, so it can only beat it by real curvature.
    """
    x, y = _check_xy(x, y, min_n=3)
    x_ref = float(np.exp(np.mean(np.log(x))))
    xs = x / x_ref
    alphas = DEFAULT_ALPHAS if alphas is None else np.asarray(alphas, dtype=np.float64)

    def solve(al: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        z = xs[None, :] ** (-al[:, None])  # (A, n)
        dz = z - z.mean(axis=1, keepdims=True)
        dy = y - y.mean()
        szz = np.einsum("an,an->a", dz, dz)
        szy = dz @ dy
        beta = np.where(szz > 0, szy / np.where(szz > 0, szz, 1.0), 0.0)
        c = y.mean() - beta * z.mean(axis=1)
        sse = float(dy @ dy) - beta * szy
        return c, beta, np.maximum(sse, 0.0)

    _, _, sse = solve(alphas)
    i = int(np.argmin(sse))
    lo, hi = alphas[max(i - 1, 0)], alphas[min(i + 1, alphas.size - 1)]
    g = (math.sqrt(5) - 1) / 2
    for _ in range(60):  # golden section on log α inside the bracketing grid cells
        a1 = math.exp(math.log(hi) - g * (math.log(hi) - math.log(lo)))
        a2 = math.exp(math.log(lo) + g * (math.log(hi) - math.log(lo)))
        s1, s2 = solve(np.array([a1, a2]))[2]
        if s1 < s2:
            hi = a2
        else:
            lo = a1
    best = np.array([math.sqrt(lo * hi), alphas[i]])
    c, beta, sse = solve(best)
    j = int(np.argmin(sse))
    return SaturatingFit(c=float(c[j]), k=float(-beta[j]), alpha=float(best[j]), x_ref=x_ref,
                         sse=float(sse[j]), n=int(x.size))


@dataclass(frozen=True)
class ModelComparison:
    """Leave-one-out comparison of the log-linear and saturating laws on the same points."""

    loo_rmse: dict[str, float]
    loo_mae: dict[str, float]
    in_sample_rmse: dict[str, float]
    best: str
    log_linear: LogLinearFit
    saturating: SaturatingFit

    def to_dict(self) -> dict[str, Any]:
        return {"loo_rmse": self.loo_rmse, "loo_mae": self.loo_mae, "in_sample_rmse": self.in_sample_rmse,
                "best": self.best,
                "saturating": {"c": self.saturating.c, "k": self.saturating.k, "alpha": self.saturating.alpha,
                               "x_ref": self.saturating.x_ref}}

    def summary(self) -> str:
        lines = ["model        LOO RMSE   LOO MAE   in-sample RMSE"]
        for m in ("log_linear", "saturating"):
            lines.append(f"{m:<12} {self.loo_rmse[m]:9.4f} {self.loo_mae[m]:9.4f} {self.in_sample_rmse[m]:12.4f}")
        lines.append(f"saturating fit: {self.saturating.equation()}")
        lines.append(f"lower held-out error: {self.best}")
        return "\n".join(lines)


def compare_models(x: Any, y: Any) -> ModelComparison:
    """Leave-one-out held-out error of both laws (needs ≥ 4 points so each saturating fit has 3)."""
    x, y = _check_xy(x, y, min_n=4)
    n = x.size
    u = np.log10(x)
    err = {"log_linear": np.empty(n), "saturating": np.empty(n)}
    for i in range(n):
        keep = np.arange(n) != i
        if np.ptp(x[keep]) == 0:
            raise ValueError("leave-one-out needs at least two distinct x in every subset")
        a, b = _ols(u[keep], y[keep])
        err["log_linear"][i] = y[i] - (a * u[i] + b)
        err["saturating"][i] = y[i] - float(fit_saturating(x[keep], y[keep]).predict(x[i]))
    ll = fit_log_linear(x, y, method="t")
    sat = fit_saturating(x, y)
    rmse = {k: float(np.sqrt(np.mean(v ** 2))) for k, v in err.items()}
    mae = {k: float(np.mean(np.abs(v))) for k, v in err.items()}
    ins = {"log_linear": float(np.sqrt(np.mean((y - ll.predict(x)) ** 2))),
           "saturating": float(np.sqrt(sat.sse / n))}
    return ModelComparison(loo_rmse=rmse, loo_mae=mae, in_sample_rmse=ins, best=min(rmse, key=rmse.get),
                           log_linear=ll, saturating=sat)


# ----------------------------------------------------------------------------------------------
# Extrapolation check


@dataclass(frozen=True)
class ExtrapolatedPoint:
    run_id: str
    label: str
    x: float
    actual: float
    actual_ci: float | None
    predicted: float
    pi_low: float
    pi_high: float
    saturating_predicted: float | None

    @property
    def inside(self) -> bool:
        return self.pi_low <= self.actual <= self.pi_high


@dataclass(frozen=True)
class Extrapolation:
    """Fit below ``cut``, prediction vs actual above it."""

    cut: float
    x_name: str
    y_name: str
    fit: LogLinearFit
    points: tuple[ExtrapolatedPoint, ...]
    fit_run_ids: tuple[str, ...] = field(default=())

    @property
    def rmse(self) -> float:
        return float(np.sqrt(np.mean([(p.actual - p.predicted) ** 2 for p in self.points])))

    @property
    def coverage(self) -> float:
        return float(np.mean([p.inside for p in self.points]))

    def to_dict(self) -> dict[str, Any]:
        return {
            "cut": self.cut, "x": self.x_name, "y": self.y_name, "level": self.fit.level,
            "n_fit": self.fit.n, "n_test": len(self.points), "fit": self.fit.to_dict(),
            "rmse": self.rmse, "coverage": self.coverage,
            "points": [{"run_id": p.run_id, "label": p.label, "x": p.x, "actual": p.actual,
                        "actual_ci": p.actual_ci, "predicted": p.predicted, "pi": [p.pi_low, p.pi_high],
                        "inside": p.inside, "saturating_predicted": p.saturating_predicted}
                       for p in self.points],
        }

    def summary(self) -> str:
        pct = f"{100 * self.fit.level:g}%"
        head = (f"fit on {self.fit.n} runs with {self.x_name} < {self.cut:.4g}: {self.fit.equation()} "
                f"(r = {self.fit.r:.3f})")
        w = max(12, len(self.x_name))
        lines = [head, f"{'run':<24} {self.x_name:>{w}} {'actual':>8} {'predicted':>9} {pct + ' PI':>19} "
                       f"{'in':>3} {'saturating':>10}"]
        for p in self.points:
            sat = "" if p.saturating_predicted is None else f"{p.saturating_predicted:10.4f}"
            lines.append(f"{p.label[:24]:<24} {p.x:{w}.4g} {p.actual:8.4f} {p.predicted:9.4f} "
                         f"[{p.pi_low:8.4f},{p.pi_high:8.4f}] {'yes' if p.inside else 'no':>3} {sat}")
        lines.append(f"held-out RMSE {self.rmse:.4f}; {pct} PI coverage {self.coverage:.2f} "
                     f"({sum(p.inside for p in self.points)}/{len(self.points)})")
        return "\n".join(lines)


def extrapolate(rows: Sequence[Mapping[str, Any]], cut: float, *, x: str = "flops", y: str = "rprec_top3",
                level: float = 0.95, n_boot: int = 2000, seed: int = 0) -> Extrapolation:
    """Fit y vs x on the runs with x < ``cut`` and predict the runs with x ≥ ``cut``."""
    xs, ys, used = select_xy(rows, x, y)
    below, above = xs < cut, xs >= cut
    if below.sum() < 3:
        raise ValueError(f"need at least 3 runs below the cut {cut:g} to fit, got {int(below.sum())}")
    if not above.any():
        raise ValueError(f"no runs at or above the cut {cut:g} to predict")
    xc, yc = resolve_column(x, rows), resolve_column(y, rows)
    fit = fit_log_linear(xs[below], ys[below], level=level, n_boot=n_boot, seed=seed, x_name=xc, y_name=yc)
    sat = fit_saturating(xs[below], ys[below]) if below.sum() >= 4 else None
    lo, hi = fit.prediction_interval(xs[above])
    pred = fit.predict(xs[above])
    pts = []
    for j, i in enumerate(np.flatnonzero(above)):
        r = used[i]
        pts.append(ExtrapolatedPoint(
            run_id=str(r["run_id"]), label=config_label(r), x=float(xs[i]), actual=float(ys[i]),
            actual_ci=r.get(f"{yc}_ci"), predicted=float(pred[j]), pi_low=float(lo[j]), pi_high=float(hi[j]),
            saturating_predicted=None if sat is None else float(sat.predict(xs[i]))))
    pts.sort(key=lambda p: p.x)
    return Extrapolation(cut=float(cut), x_name=xc, y_name=yc, fit=fit, points=tuple(pts),
                         fit_run_ids=tuple(str(used[i]["run_id"]) for i in np.flatnonzero(below)))


def chance_level(y: str, rows: Sequence[Mapping[str, Any]] = (), block: int | None = None) -> float | None:
    """Chance value of an R-Precision column: top-k of a block of B candidates is k/B (3/32 for top-3
    at block 32). The block comes from ``block``, else the rows' ``rprec_block``, else 32 (Table 2)."""
    if not y.startswith("rprec_top"):
        return None
    k = int(y[len("rprec_top"):])
    if block is None:
        blocks = {r.get("rprec_block") for r in rows if r.get("rprec_block") is not None}
        block = blocks.pop() if len(blocks) == 1 else 32
    return k / block
