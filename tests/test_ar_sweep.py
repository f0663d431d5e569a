"""A real tiny AR sweep through the launcher (issue 30 item 5): the shared joined-text and tokenizer steps,
LM training, generation and evaluation, all real stages (no fake stage), from ``sweeps/ar_size_codebook.py``."""

import json
from pathlib import Path

import pytest
from diffusion_fixtures import make_dataset, make_evaluator

LOOP = ("train.batch_size=8", "train.log_every=2", "train.wandb=disabled", "train.optim.warmup_steps=0",
        "train.optim.lr=2e-3")


@pytest.mark.e2e
def test_real_ar_sweep_every_row_done_and_scored(tmp_path):
    from sweeps.launcher import SweepConfig, evaluator_identity, launch, load_sweep, stage_state

    data = make_dataset(tmp_path, joined=True)
    E = make_evaluator(tmp_path / "E")
    # The `cpu` preset (make sweep-ar-cpu) at 6 steps, its two smallest LM sizes: most of this test's CPU is
    # XLA compiling each size's training step and decoding loop, which grows with the depth. The tokenizer
    # is one block deep and skips its validation hook (data.eval_clips=0): nothing here reads either. Its
    # model and windows are test_fsq.py's and test_ar_family.py's tokenizer (tiny width 32, 20 frames), and
    # the 1L-32 LM is test_ar_family.py's: with one CPU device in every process of the session
    # (conftest.py), whichever runs second loads their initial-state and training-step programs from the
    # session's compilation cache.
    specs = [s for s in load_sweep("sweeps/ar_size_codebook.py", preset="cpu", steps=6, tokenizer_steps=4,
                                   codebooks=[256], lm_set=[*LOOP, "train.ckpt_every=6"],
                                   tokenizer_set=[*LOOP, "train.ckpt_every=4", "data.eval_clips=0", "model.depth=1",
                                                  "model.width=32", "data.window=20"])
             if s.axes["layers"] <= 2]
    assert [(s.axes["layers"], s.axes["dim"]) for s in specs] == [(2, 64), (1, 32)]
    from diffusion_fixtures import ENCODER

    cfg = SweepConfig(data=str(data), encoder=str(ENCODER), out=str(tmp_path / "sweep"), evaluator=str(E),
                      eval_limit=4, rprec_block=4)
    # "Killed" after the first run: only it finished. Relaunching the whole sweep (submitit's in-process debug
    # executor) leaves that run as it is and takes the other through every stage.
    launch(specs[:1], cfg)
    first = tmp_path / "sweep/runs" / specs[0].name
    assert all(stage_state(cfg, specs[0]).values()) and not any(stage_state(cfg, specs[1]).values())
    mtimes = {f: (first / f).stat().st_mtime_ns for f in ("metrics.jsonl", "generated.npz", "eval.json")}
    res = launch(specs, SweepConfig(**{**cfg.__dict__, "executor": "debug"}))
    assert not res.failed, res.failed
    assert {f: (first / f).stat().st_mtime_ns for f in mtimes} == mtimes
    rows = [json.loads(x) for x in Path(res.results).read_text().splitlines()]
    eid = evaluator_identity(E)[0]
    assert [(r["run_id"], r["status"]) for r in rows] == [(s.name, "done") for s in specs]
    for r, s in zip(rows, specs):
        assert r["family"] == "ar" and r["codebook"] == 256 and r["evaluator_id"] == eid
        assert (r["layers"], r["dim"]) == (s.axes["layers"], s.axes["dim"])
        assert 0 <= r["rprec_top3"] <= 1 and r["rprec_top1"] <= r["rprec_top3"] and r["fid"] >= 0
        assert r["params"] > 0 and r["flops_per_sample"] > 0 and r["steps"] == 6
    assert rows[0]["params"] > rows[1]["params"]
    # One tokenizer, keyed by its codebook, trained once and shared by both LM sizes; the launcher passed it
    # as --tokenizer (the registry's "needs") and the generate stage only family-agnostic arguments (the
    # run's own sampling, temperature 0.6 in this preset, as --set sample.*).
    provs = [json.loads((tmp_path / "sweep/runs" / s.name / "provenance.json").read_text()) for s in specs]
    toks = {p["steps"]["tokenizer-K256"]["dir"] for p in provs}
    assert len(toks) == 1 and len(list((tmp_path / "sweep/steps").glob("tokenizer-K256-*"))) == 1
    tok = Path(toks.pop())
    assert json.loads((tok / "config.json").read_text())["codebook"] == 256
    assert (tok / "step.log").read_text().count(" train tokenizer ") == 1
    for p in provs:
        train, gen = p["stages"]["train"]["argv"], p["stages"]["generate"]["argv"]
        assert train[train.index("--tokenizer") + 1] == str(tok)
        assert not {"--sampler", "--steps", "--temperature"} & set(gen)
        assert gen[gen.index("--set") + 1] == "sample.temperature=0.6"
