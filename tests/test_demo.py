"""make demo's closing verdict (handx_jax/demo.py): does its mini sweep's curve rise, and the committed
`make sweep-cpu` curve beside it. No training here: rows with known numbers."""

import json

from handx_jax import standard
from handx_jax.demo import committed_study, rises, verdict


def _rows(top3, ci, flops=(1e11, 1e12, 1e13)):
    return [{"run_id": f"r{i}", "train_flops": f, "rprec_top3": t, "rprec_top3_ci": c, "rprec_block": 32}
            for i, (f, t, c) in enumerate(zip(flops, top3, ci))]


def test_rises_needs_a_positive_slope_and_the_largest_run_above_chance():
    fit = {"slope": 0.02, "slope_ci": [0.01, 0.03], "r": 0.9}
    assert rises(_rows((0.10, 0.12, 0.15), (0.02, 0.02, 0.03)), fit)[0]  # 0.15 - 0.03 = 0.12 > 3/32
    ok, why = rises(_rows((0.10, 0.12, 0.12), (0.02, 0.02, 0.03)), fit)  # 0.12 - 0.03 = 0.09 < 0.09375
    assert not ok and "lower end 0.090, chance 0.094" in why and "largest run r2" in why
    # issue 31's demo: top-3 0.170 / 0.083 / 0.136, slope -0.070 per decade
    assert not rises(_rows((0.170, 0.083, 0.136), (0.08, 0.06, 0.03)), {**fit, "slope": -0.070})[0]


def test_verdict_fits_the_sweep_and_shows_the_committed_study(tmp_path, capsys):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    rows = [{**r, "family": "diffusion", "status": "done"} for r in _rows((0.10, 0.08, 0.06), (0.02, 0.02, 0.02))]
    (sweep / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert verdict(sweep, tmp_path) is False
    out = capsys.readouterr().out
    assert "the demo's curve does NOT rise: slope -0.0200 per decade" in out and "r -1.000" in out
    assert "does not show the scaling" in out and "too noisy to pin the slope down" in out
    assert "demo takes 10 min with its install on 2 quiet cores under v8, measured; 5 min 44 s under v7" in out  # the measured time, said in the output
    STUDY, version = committed_study()
    assert (STUDY / "fit.txt").read_text().splitlines()[1] in out  # the committed fit, line for line
    assert (tmp_path / "sweep-cpu-fit.png").read_bytes() == (STUDY / "fit.png").read_bytes()
    # A study under another standard evaluator is said to be another yardstick, never "same evaluator".
    assert ("same evaluator" in out) == (version == standard.VERSION)
    if version != standard.VERSION:
        assert f"NOT this demo's v{standard.VERSION}: another yardstick" in out


def test_demo_preset_is_the_studys_sizes_with_data_seen_growing_with_size():
    """make demo's mini sweep: the study's three sizes on all the prefix's clips, at the steps of the study's
    20% runs (150 / 300 / 600: data seen grows with size, as the matched design's)."""
    from sweeps.launcher import load_sweep

    def steps(preset, frac):
        return {s.axes["dim"]: int(dict(o.split("=", 1) for o in s.overrides)["train.steps"])
                for s in load_sweep("sweeps/diffusion_cpu_study.py", preset=preset) if s.axes["data_fraction"] == frac}

    assert steps("demo", 1.0) == steps("matched", 0.2) == {32: 150, 64: 300, 128: 600}
    assert [s.axes["dim"] for s in load_sweep("sweeps/diffusion_cpu_study.py", preset="demo")] == [128, 64, 32]
