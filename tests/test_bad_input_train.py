"""Bad input to ``handx train`` (issue 54): training values that cannot be run (a step count, batch or
interval of 0, a negative step count, a non-finite learning rate) are one line and exit 2 before the run
folder exists, for every family (the one config system checks the loop's ``train.*`` group); a run killed
with -9 before its first checkpoint resumes without a second copy of any metrics row (a real process); a
run that diverges is one line. (A G-HTT P run's damaged frame statistics: tests/test_bad_input_files.py.)
Milliseconds each, but the kill (a process of its own, ~3 CPU-s)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from handx_jax.cli import main

BAD_SETS = {
    "train.ckpt_every=0": "train.ckpt_every must be a whole number >= 1, got 0",
    "train.log_every=0": "train.log_every must be a whole number >= 1, got 0",
    "train.batch_size=0": "train.batch_size must be a whole number >= 1, got 0",
    "train.steps=0": "train.steps must be a whole number >= 1, got 0",
    "train.steps=-5": "train.steps must be a whole number >= 1, got -5",
    "train.optim.lr=nan": "train.optim.lr must be a finite number >= 0, got nan",
    "train.optim.lr=inf": "train.optim.lr must be a finite number >= 0, got inf",
    "train.seed=-1": "train.seed must be a whole number >= 0, got -1",
    "train.ema_decay=1": "train.ema_decay must be a finite number >= 0 and < 1, got 1.0 (0 disables EMA)",
    "train.optim.b2=nan": "train.optim.b2 must be a finite number >= 0 and < 1, got nan",
}


@pytest.mark.parametrize("setting", sorted(BAD_SETS))
def test_a_training_value_that_cannot_run_is_one_line_before_the_run_folder(tmp_path, capsys, setting):
    out = tmp_path / "P"
    rc = main(["train", "ghtt-pose", "--data", str(tmp_path / "D"), "--preset", "tiny", "--set", setting,
               "--out", str(out)])
    assert (rc, capsys.readouterr().err.strip()) == (2, f"handx train ghtt-pose: error: {BAD_SETS[setting]}")
    assert not out.exists()  # nothing written: the corrected rerun is not "a different configuration"


@pytest.mark.parametrize("family, extra", [("diffusion", ["--encoder", "E", "--set", "train.ckpt_every=0"]),
                                           ("tokenizer", ["--set", "train.ckpt_every=0"]),
                                           ("evaluator", ["--encoder", "E", "--batch-size", "0"])])
def test_every_family_checks_the_same_training_values(tmp_path, capsys, family, extra):
    rc = main(["train", family, "--data", str(tmp_path / "D"), *extra, "--out", str(tmp_path / "R")])
    err = capsys.readouterr().err.strip()
    key = "train.batch_size" if family == "evaluator" else "train.ckpt_every"
    assert (rc, err) == (2, f"handx train {family}: error: {key} must be a whole number >= 1, got 0")
    assert not (tmp_path / "R").exists()


def test_the_loop_refuses_a_bad_config_built_in_code_before_writing(tmp_path):
    from handx_jax.config import ConfigError
    from handx_jax.train import TrainConfig, TrainSpec, train

    spec = TrainSpec(init=lambda k: {}, loss=None, cfg=TrainConfig(steps=4, log_every=0), config={"family": "x"})
    with pytest.raises(ConfigError, match=r"^train\.log_every must be a whole number >= 1, got 0$"):
        train(tmp_path / "run", spec)
    assert not (tmp_path / "run").exists()


def test_edges_of_the_training_ranges_are_accepted():
    from handx_jax.families.ghtt.pose import make_config

    cfg = make_config("tiny", ["train.steps=1", "train.ckpt_every=1", "train.log_every=1", "train.batch_size=1",
                               "train.seed=0", "train.optim.lr=0", "train.ema_decay=0.999", "train.eval_every=0"])
    assert (cfg.train.steps, cfg.train.optim.lr) == (1, 0.0)


def test_kill_9_before_the_first_checkpoint_leaves_no_metrics_row_twice(tmp_path):
    """A real training process killed after its step-0 evaluation and a few steps, before any checkpoint;
    the resumed run starts over at step 0 and its metrics.jsonl holds each row once."""
    import train_kill_worker as worker

    from handx_jax.infra.readers import read_jsonl

    run = tmp_path / "run"
    metrics = run / "metrics.jsonl"
    p = subprocess.Popen([sys.executable, str(Path(worker.__file__)), str(run)], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])})
    deadline = time.time() + 120
    while time.time() < deadline and p.poll() is None:
        if metrics.exists() and len(metrics.read_text().splitlines()) >= 4:  # eval row + 3 training rows
            break
        time.sleep(0.05)
    assert p.poll() is None, p.stderr.read().decode()[-2000:]
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    before = read_jsonl(metrics, strict=False)  # a kill mid-line leaves a torn last line
    assert before[0]["step"] == 0 and "eval/mse" in before[0] and not (run / "checkpoints" / "1").exists()
    worker.run(run, stop_at=3)  # the rerun, as if killed again after step 3
    rows = [json.loads(x) for x in metrics.read_text().splitlines()]
    assert [(r["step"], "eval/mse" in r) for r in rows] == [(0, True), (1, False), (2, False), (3, False)]
    assert rows[0]["eval/mse"] == before[0]["eval/mse"]  # the same untrained model's numbers, logged once


def test_a_run_that_diverges_is_one_line(tmp_path, capsys, monkeypatch):
    """A loss that turns NaN under finite settings (the loop's FloatingPointError) is one line, not a traceback."""
    from handx_jax.families.ghtt import pose

    def diverging(run_dir, cfg, **kw):
        raise FloatingPointError(f"loss is nan at step 5 (run {run_dir})")

    monkeypatch.setattr(pose, "train", diverging)
    out = tmp_path / "P"
    assert main(["train", "ghtt-pose", "--data", str(tmp_path / "D"), "--set", "train.optim.lr=1e30", "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"handx train ghtt-pose: error: loss is nan at step 5 (run {out}): the run diverged (try a lower "
        "train.optim.lr in a new --out; the folder keeps its checkpoints from before)")
