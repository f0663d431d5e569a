"""Which way of spending compute pays: y = a + Σ_j b_j·log10(x_j), against the one-axis fit.

A sweep over model size × data (Table 2's layers × data fraction, the CPU study's sizes × fractions
at fixed epochs) spends training compute two ways: per-sample FLOPs (a larger model) and samples
seen (more steps). ``handx analyze fit --x compute`` puts both on one axis, which assumes a decade
of either buys the same. :func:`fit_factors` fits a slope per factor instead and tests that
assumption: the one-axis ("pooled") model y = a + b·log10(Π_j x_j) is the factor model with every
b_j equal, so an F test with k − 1 and n − k − 1 degrees of freedom compares the two (nested OLS
models). With the analytic per-sample FLOPs and the samples seen as the factors, Π_j x_j is the
training compute up to the factor 3 (forward + backward), so the pooled fit is the ``--x compute``
fit. This is the Chinchilla-style reading (loss as a function of parameters and tokens, not of their
product alone), on the log-linear scale the paper uses for R-Precision.

Intervals are the classical OLS t-intervals; with the few runs of a sweep they are wide, and the
summary says how many residual degrees of freedom they rest on. Leave-one-out RMSE (from the hat
matrix, no refits) compares the two models' predictions of a held-out run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.stats import f as f_dist, t as student_t

from analysis.schema import GROUND_TRUTH
from analysis.selection import resolve_column, select_rows

DEFAULT_FACTORS = ("flops_analytic", "samples")


@dataclass(frozen=True)
class FactorFit:
    """y = intercept + Σ_j slopes[j]·log10(x_j), and the pooled one-axis fit it is tested against."""

    factors: tuple[str, ...]  # column names, in the order of ``slopes``
    y_name: str
    n: int
    level: float
    intercept: float
    slopes: tuple[float, ...]  # per decade of each factor
    slope_se: tuple[float, ...]
    slope_ci: tuple[tuple[float, float], ...]
    r2: float
    resid_std: float  # with n − k − 1 degrees of freedom
    loo_rmse: float
    pooled_slope: float  # per decade of the product of the factors
    pooled_slope_ci: tuple[float, float]
    pooled_intercept: float
    pooled_r2: float
    pooled_loo_rmse: float
    f_stat: float  # H0: every slope is the same (the pooled model); k − 1 and n − k − 1 dof
    p_value: float

    @property
    def dof(self) -> int:
        return self.n - len(self.factors) - 1

    def predict(self, xs: Sequence[Any]) -> np.ndarray:
        """y at factor values ``xs`` (one array per factor, in ``factors`` order)."""
        u = [np.log10(np.asarray(x, dtype=np.float64)) for x in xs]
        return self.intercept + sum(b * uj for b, uj in zip(self.slopes, u))

    def to_dict(self) -> dict[str, Any]:
        return {"y": self.y_name, "n": self.n, "level": self.level, "dof": self.dof,
                "factors": {name: {"slope": b, "se": se, "ci": list(ci)}
                            for name, b, se, ci in zip(self.factors, self.slopes, self.slope_se, self.slope_ci)},
                "intercept": self.intercept, "r2": self.r2, "resid_std": self.resid_std, "loo_rmse": self.loo_rmse,
                "pooled": {"x": " × ".join(self.factors), "slope": self.pooled_slope,
                           "slope_ci": list(self.pooled_slope_ci), "intercept": self.pooled_intercept,
                           "r2": self.pooled_r2, "loo_rmse": self.pooled_loo_rmse},
                "equal_slopes_test": {"f": self.f_stat, "df": [len(self.factors) - 1, self.dof],
                                      "p_value": self.p_value}}

    def summary(self) -> str:
        pct = f"{100 * self.level:g}%"
        terms = " ".join(f"{'−' if b < 0 else '+'} {abs(b):.4f}·log10({name})" for name, b in zip(self.factors, self.slopes))
        lines = [f"{self.y_name} = {self.intercept:.4f} {terms}",
                 f"  n = {self.n} runs, {self.dof} residual degrees of freedom; R² = {self.r2:.3f}, "
                 f"residual std {self.resid_std:.4f}, leave-one-out RMSE {self.loo_rmse:.4f}"]
        for name, b, se, (lo, hi) in zip(self.factors, self.slopes, self.slope_se, self.slope_ci):
            lines.append(f"  per decade of {name}: {b:+.4f} ± {se:.4f} (se); {pct} t CI [{lo:.4f}, {hi:.4f}]")
        lo, hi = self.pooled_slope_ci
        lines += [f"one axis ({' × '.join(self.factors)}): {self.pooled_slope:+.4f} per decade, {pct} t CI "
                  f"[{lo:.4f}, {hi:.4f}]; R² = {self.pooled_r2:.3f}, leave-one-out RMSE {self.pooled_loo_rmse:.4f}",
                  f"equal slopes (the one-axis model): F({len(self.factors) - 1}, {self.dof}) = {self.f_stat:.3f}, "
                  f"p = {self.p_value:.4f}"]
        return "\n".join(lines)


def _ols(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Coefficients, their covariance, the residual sum of squares and the leave-one-out residuals."""
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ beta
    rss = float(resid @ resid)
    xtx_inv = np.linalg.inv(X.T @ X)
    dof = X.shape[0] - X.shape[1]
    cov = xtx_inv * (rss / dof)
    h = np.einsum("ij,jk,ik->i", X, xtx_inv, X)  # leverages
    return beta, cov, rss, resid / (1.0 - h)


def fit_factor_arrays(xs: Sequence[Any], y: Any, *, names: Sequence[str] | None = None, y_name: str = "y",
                      level: float = 0.95) -> FactorFit:
    """Fit y on log10 of each factor in ``xs`` (arrays of the same length as ``y``)."""
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    y = np.asarray(y, dtype=np.float64).ravel()
    k = len(xs)
    names = tuple(names) if names is not None else tuple(f"x{j + 1}" for j in range(k))
    if k < 2:
        raise ValueError(f"need at least two factors to compare, got {k}")
    if len(set(names)) != k:
        raise ValueError(f"factors must differ, got {', '.join(names)}")
    cols = [np.asarray(x, dtype=np.float64).ravel() for x in xs]
    for name, c in zip(names, cols):
        if c.shape != y.shape:
            raise ValueError(f"factor {name} has {c.size} values for {y.size} runs")
        if not np.all(np.isfinite(c)) or np.any(c <= 0):
            raise ValueError(f"factor {name} must be finite and > 0 for a log10 fit")
    if not np.all(np.isfinite(y)):
        raise ValueError(f"{y_name} must be finite")
    if y.size < k + 2:
        raise ValueError(f"need at least {k + 2} runs for {k} factors (one residual degree of freedom), got {y.size}")
    u = np.stack([np.log10(c) for c in cols], axis=1)
    X = np.column_stack([np.ones(y.size), u])
    if np.linalg.matrix_rank(X) < k + 1:
        raise ValueError(f"the factors {', '.join(names)} do not vary independently in these runs (one is a "
                         "function of the others): their separate slopes are not identified")
    n, dof = y.size, y.size - k - 1
    beta, cov, rss, loo = _ols(X, y)
    Xp = np.column_stack([np.ones(n), u.sum(axis=1)])
    beta_p, cov_p, rss_p, loo_p = _ols(Xp, y)
    syy = float(((y - y.mean()) ** 2).sum())
    se = np.sqrt(np.diag(cov))
    tq = float(student_t.ppf(0.5 + level / 2, dof))
    tq_p = float(student_t.ppf(0.5 + level / 2, n - 2))
    f_stat = max(rss_p - rss, 0.0) / (k - 1) / (rss / dof) if rss > 0 else math.inf
    p = float(f_dist.sf(f_stat, k - 1, dof)) if math.isfinite(f_stat) else 0.0
    se_p = math.sqrt(cov_p[1, 1])
    return FactorFit(
        factors=names, y_name=y_name, n=n, level=level, intercept=float(beta[0]),
        slopes=tuple(float(b) for b in beta[1:]), slope_se=tuple(float(s) for s in se[1:]),
        slope_ci=tuple((float(b - tq * s), float(b + tq * s)) for b, s in zip(beta[1:], se[1:])),
        r2=1.0 - rss / syy if syy > 0 else float("nan"), resid_std=math.sqrt(rss / dof),
        loo_rmse=float(np.sqrt(np.mean(loo ** 2))), pooled_slope=float(beta_p[1]),
        pooled_slope_ci=(float(beta_p[1] - tq_p * se_p), float(beta_p[1] + tq_p * se_p)),
        pooled_intercept=float(beta_p[0]), pooled_r2=1.0 - rss_p / syy if syy > 0 else float("nan"),
        pooled_loo_rmse=float(np.sqrt(np.mean(loo_p ** 2))), f_stat=f_stat, p_value=p)


def fit_factors(rows: Sequence[Mapping[str, Any]], factors: Sequence[str] = DEFAULT_FACTORS,
                y: str = "rprec_top3", *, level: float = 0.95) -> FactorFit:
    """:func:`fit_factor_arrays` over the rows (ground truth excluded) that carry every factor and ``y``.
    Factor and metric names are columns or the aliases of ``handx analyze fit`` (``flops_analytic``,
    ``samples``, ``params``, ``data``, ...)."""
    cols = [resolve_column(f, rows) for f in factors]
    yc = resolve_column(y, rows)
    runs = [r for r in rows if r.get("family") != GROUND_TRUTH]
    for c in (*cols, yc):
        if runs and not any(r.get(c) is not None for r in runs):
            raise ValueError(f"no run in these results carries {c!r}")
    used, _ = select_rows(rows, (*cols, yc), log_axis=cols)  # select_rows names what it leaves out
    return fit_factor_arrays([[float(r[c]) for r in used] for c in cols], [float(r[yc]) for r in used],
                             names=cols, y_name=yc, level=level)
