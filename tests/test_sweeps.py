"""The sweep launcher: runs every spec, skips finished stages on re-run, collects a results table."""

import json

import pytest

from sweeps.launcher import RunSpec, SweepConfig, launch, load_sweep, stage_state, status

from diffusion_fixtures import ENCODER, make_dataset

TINY = ("model.layers=1", "model.dim=32", "model.heads=4", "model.ff=64", "train.steps=4", "train.batch_size=8",
        "train.log_every=2", "train.ckpt_every=2", "train.wandb=disabled")


def test_sweep_files_define_the_grids(tmp_path):
    cpu = load_sweep("sweeps/diffusion_scaling.py")
    paper = load_sweep("sweeps/diffusion_scaling.py", grid="paper")
    assert len(cpu) == 4 and len({s.name for s in cpu}) == 4
    assert [s.overrides[:2] for s in paper][0] == ("model.layers=2", "model.dim=256")
    assert all("data.fraction=0.05" in s.overrides for s in paper)  # Table B uses the 5% split
    bad = tmp_path / "bad.py"
    bad.write_text("from sweeps.launcher import RunSpec\ndef runs():\n    return [RunSpec('a'), RunSpec('a')]\n")
    with pytest.raises(ValueError, match="unique"):
        load_sweep(bad)


@pytest.mark.slow
def test_launch_resume_and_results(tmp_path):
    data = make_dataset(tmp_path)
    specs = [RunSpec("a", overrides=TINY), RunSpec("b", overrides=TINY + ("data.fraction=0.2",))]
    cfg = SweepConfig(data=str(data), encoder=str(ENCODER), out=str(tmp_path / "sweep"))
    # "Killed" after the first run: only it finished.
    launch(specs[:1], cfg)
    assert stage_state(cfg, specs[0])["train"] and not stage_state(cfg, specs[1])["train"]
    mtime = (tmp_path / "sweep/runs/a/metrics.jsonl").stat().st_mtime_ns
    # Re-running the whole sweep skips the finished run and completes the other (debug = submitit path).
    out = launch(specs, SweepConfig(**{**cfg.__dict__, "executor": "debug"}))
    assert (tmp_path / "sweep/runs/a/metrics.jsonl").stat().st_mtime_ns == mtime
    rows = [json.loads(l) for l in out.read_text().splitlines()]
    assert [r["run_id"] for r in rows] == ["a", "b"]
    assert rows[1]["data_fraction"] == 0.2 and rows[0]["params"] > 0 and rows[0]["flops_per_sample"] > 0
    assert [s["train"] for s in status(tmp_path / "sweep")] == [True, True]
