"""Replicates (runs of one configuration that differ only in seed) averaged before a fit."""

import json

import numpy as np
import pytest
from scipy import stats

from analysis.replicates import mean_replicates
from tests.test_analysis_paper import run_cli


def rows():
    out = []
    for i, (f, ys) in enumerate([(1e11, (0.12, 0.15)), (1e12, (0.16, 0.14)), (1e13, (0.21, 0.25)),
                                 (1e14, (0.27,))]):
        for seed, y in zip((42, 1), ys):
            out.append(dict(run_id=f"c{i}-s{seed}", family="diffusion", layers=i + 1, dim=32, steps=100,
                            data_fraction=1.0, train_flops=f, flops_per_sample=f / 1e6, seed=seed,
                            rprec_top3=y, rprec_top3_ci=0.01, fid=30.0 - i - seed / 100, wall_time_s=5.0))
    return out


def test_means_and_intervals_over_seeds():
    out = mean_replicates(rows())
    assert [r["replicates"] for r in out] == [2, 2, 2, 1]
    assert [r["run_id"] for r in out] == ["c0-s42+1", "c1-s42+1", "c2-s42+1", "c3-s42"]
    assert out[0]["replicate_run_ids"] == ["c0-s42", "c0-s1"] and "seed" not in out[0]
    for r, (a, b) in zip(out, [(0.12, 0.15), (0.16, 0.14), (0.21, 0.25)]):
        assert r["rprec_top3"] == pytest.approx((a + b) / 2)
        # n = 2: t(0.975, 1) · sd / √2 with sd = |a − b| / √2
        assert r["rprec_top3_ci"] == pytest.approx(stats.t.ppf(0.975, 1) * abs(a - b) / 2)
    assert out[3]["rprec_top3"] == 0.27 and out[3]["rprec_top3_ci"] == 0.01  # a single run keeps its own ±
    assert out[1]["fid"] == pytest.approx(29.0 - 0.43 / 2)
    # A row of another configuration (here: steps) is never merged.
    other = rows()
    other[1]["steps"] = 200
    assert [r["replicates"] for r in mean_replicates(other)] == [1, 1, 2, 2, 1]


def test_cli_fits_the_means(tmp_path, capsys):
    path = tmp_path / "r.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows()))
    rc, out = run_cli(["analyze", "fit", str(path), "--x", "compute", "--json", "--n-boot", "100",
                       "--mean-replicates"], capsys)
    d = json.loads(out)
    u = np.log10([1e11, 1e12, 1e13, 1e14])
    y = np.array([0.135, 0.15, 0.23, 0.27])
    slope, icpt = np.polyfit(u, y, 1)
    assert d["n"] == 4 and d["slope"] == pytest.approx(slope) and d["intercept"] == pytest.approx(icpt)
    assert d["r"] == pytest.approx(np.corrcoef(u, y)[0, 1])
    rc, out = run_cli(["analyze", "fit", str(path), "--x", "compute", "--json", "--n-boot", "100"], capsys)
    assert json.loads(out)["n"] == 7  # without the flag: every run
