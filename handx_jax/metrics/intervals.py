"""Replications and confidence intervals (issues 4 and 14.2). Every ± is a 95% interval computed over
values that are independent of each other, and the output says which (:func:`ci_method`):

* "groups": with G > 1 generation groups (samples per prompt), each metric is computed per group and
  the interval is the Student-t one over the G group values, t_{0.975, G−1}·s/√G (s with ddof 1).
  Groups are independent draws from the generator for the same prompts, so the interval covers the
  generation randomness, not the choice of prompts.
* "bootstrap_prompts": with one group (the Ground Truth row, or G = 1), and for MultiModality (which
  is a between-group quantity), the prompts are resampled with replacement ``cfg.bootstrap`` times
  and the interval is 1.96 × the standard deviation of the statistic over the resamples.

R-Precision blocks, Diversity pairs and MultiModality picks are still re-drawn ``replications`` times
(replication r uses its own prompt order and pairs, seeded by (seed, r)) and averaged: the
re-blockings reduce the variance of the point value, but they reuse the same samples, so their
spread is not an interval (it shrinks with R and is 0 when nothing is random: FID's old "CI" over
replications was 3e-15 for one group). In particular R-Precision's ± here is *not* the paper's: the
reference reports the standard deviation of the per-block scores over all blocks of all groups
(reference §5.4; ≈ √(p(1−p)/32) ≈ 0.08 for block 32 whatever N is), a spread of single-block
scores, while this ± is an interval for the mean and shrinks as 1/√G (groups) or 1/√N (bootstrap).
"""

from __future__ import annotations

import math

import numpy as np

from handx_jax.metrics.config import MetricConfig


CI_GROUPS = "groups"
CI_BOOTSTRAP = "bootstrap_prompts"


# Quantities between the groups of one prompt: one value per prompt, never one per group.
BETWEEN_GROUPS = frozenset({"multimodality", "apd_left", "apd_right"})


def ci_method(metric: str, groups: int) -> str:
    """How the ± of ``metric`` is computed for ``groups`` generation groups (see the module docstring)."""
    return CI_GROUPS if groups > 1 and metric not in BETWEEN_GROUPS else CI_BOOTSTRAP


def mean_ci(values) -> tuple[float, float]:
    """Mean and the 95% Student-t half-width t_{0.975, n−1}·s/√n over n independent values (0 for n = 1)."""
    from scipy.stats import t as student_t

    v = np.asarray(values, np.float64)
    if len(v) < 2:
        return float(v.mean()), 0.0
    return float(v.mean()), float(student_t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v)))


def prompt_mean_ci(values_N, cfg: MetricConfig = MetricConfig()) -> tuple[float, float]:
    """Mean and bootstrap 95% half-width (prompts resampled, :func:`bootstrap_indices`) of a per-prompt
    quantity: the "bootstrap_prompts" interval (APD here; every row of the prediction benchmark)."""
    v = np.asarray(values_N, np.float64)
    n = len(v)
    return float(np.nanmean(v)), per_prompt_ci(v, resample_counts(bootstrap_indices(n, cfg), n))


def bootstrap_indices(n: int, cfg: MetricConfig) -> np.ndarray:
    """(cfg.bootstrap, n) prompt indices drawn with replacement, fixed by the seed."""
    return np.random.default_rng([cfg.seed, 0xB0]).integers(0, n, size=(cfg.bootstrap, n))


def resample_counts(idx_BxN: np.ndarray, n: int) -> np.ndarray:
    """Multiplicity of each prompt in each resample (B, n): a per-prompt mean over a resample is counts @ v / n."""
    B = idx_BxN.shape[0]
    c = np.zeros((B, n), np.float64)
    np.add.at(c, (np.repeat(np.arange(B), idx_BxN.shape[1]), idx_BxN.reshape(-1)), 1.0)
    return c


def bootstrap_half_width(stats_B) -> float:
    """1.96 × the standard deviation of a statistic over its bootstrap resamples."""
    return float(1.96 * np.std(np.asarray(stats_B, np.float64), ddof=1)) if len(stats_B) > 1 else 0.0


def per_prompt_ci(values_N, counts_BxN) -> float:
    """Bootstrap half-width of the mean of a per-prompt quantity (NaN = no value for that prompt)."""
    v = np.asarray(values_N, np.float64)
    ok = np.isfinite(v)
    c = counts_BxN[:, ok]
    return bootstrap_half_width((c @ v[ok]) / np.maximum(c.sum(1), 1.0))

