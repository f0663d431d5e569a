"""Bad input to ``handx sweep`` (issue 31 items 5, 6): a sweep file is validated when it is loaded, so
a ``runs()`` that raises, returns None or nothing, a syntax error or duplicate run ids are one line
naming the file (exit 2, no traceback, no sweep folder made); ``sweep status`` on a corrupt
``sweep.json`` says it is corrupt, not that there is none. In-process, no training: milliseconds."""

import json
from pathlib import Path

import pytest

from handx_jax.cli import main
from sweeps.launcher import load_sweep

SWEEPS = {
    "raises": ("def runs(**kw):\n    raise RuntimeError('no such size')\n", "runs() raised RuntimeError: no such size"),
    "returns_none": ("def runs(**kw):\n    pass\n", "runs() returned None, not a list of RunSpec"),
    "no_runs": ("def runs(**kw):\n    return []\n", "runs() returned no runs"),
    "syntax": ("def runs(**kw)\n    return []\n", "syntax error at line 1"),
    "import_fails": ("import no_such_module_31\ndef runs(**kw):\n    return []\n",
                     "failed to import: ModuleNotFoundError: No module named 'no_such_module_31'"),
    "no_runs_function": ("RUNS = []\n", "defines no runs(**kw) function"),
    "duplicate_ids": ("from sweeps.launcher import RunSpec\ndef runs(**kw):\n"
                      "    return [RunSpec('L2'), RunSpec('L4'), RunSpec('L2')]\n", "run names must be unique; repeated: L2"),
    "not_runspecs": ("def runs(**kw):\n    return ['L2']\n", "runs() item 0 is a str, not a RunSpec"),
    "bad_name": ("from sweeps.launcher import RunSpec\ndef runs(**kw):\n    return [RunSpec('../x')]\n",
                 "run name '../x' is not allowed"),
}


@pytest.mark.parametrize("case", sorted(SWEEPS))
@pytest.mark.parametrize("dry_run", [True, False])
def test_bad_sweep_file_is_one_line_naming_it(tmp_path, capsys, case, dry_run):
    text, words = SWEEPS[case]
    f = tmp_path / f"{case}.py"
    f.write_text(text)
    out = tmp_path / "out"
    argv = ["sweep", "run", str(f), "--out", str(out), "--data", str(tmp_path), "--encoder", str(tmp_path)]
    assert main(argv + (["--dry-run"] if dry_run else [])) == 2
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert err.startswith(f"handx sweep run: error: file {f}: ") and words in err, err
    assert "\n" not in err and "Traceback" not in err and cap.out == ""
    assert not out.exists()  # nothing launched, nothing left behind


def test_load_sweep_refuses_through_the_api_too(tmp_path):
    f = tmp_path / "s.py"
    f.write_text(SWEEPS["returns_none"][0])
    with pytest.raises(ValueError, match="returned None"):
        load_sweep(f)


@pytest.mark.parametrize("content, words", [("{\"config\": ", "corrupt JSON"),
                                            ("[1, 2]", "not a sweep record"),
                                            ('{"config": {"nope": 1}, "runs": []}', "damaged sweep record")])
def test_sweep_status_on_a_corrupt_sweep_json_names_it(tmp_path, capsys, content, words):
    (tmp_path / "sweep.json").write_text(content)
    assert main(["sweep", "status", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"handx sweep status: error: file {tmp_path / 'sweep.json'}: ") and words in err
    assert "no sweep.json" not in err and "\n" not in err
    assert (tmp_path / "sweep.json").read_text() == content  # not rewritten


def test_sweep_status_without_sweep_json_still_says_so(tmp_path, capsys):
    assert main(["sweep", "status", "--out", str(tmp_path)]) == 2
    assert "not a sweep folder (no sweep.json)" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------
# Issue 54: the launcher's numbers and flags, damaged state files, idempotent relaunches


SWEEP_FILE = ("import sys\nfrom sweeps.launcher import RunSpec\n"
              "def runs(**kw):\n    return [RunSpec('a', 'diffusion', command=(sys.executable, '-c', 'pass'))]\n")


@pytest.mark.parametrize("flags, words", [
    (["--eval-limit", "-1", "--eval-samples", "0"], "--eval-limit must be a whole number >= 1, got -1"),
    (["--eval-samples", "0"], "--eval-samples must be a whole number >= 1, got 0"),
    (["--max-parallel", "0"], "--max-parallel must be a whole number >= 1, got 0"),
    (["--set", "foo=1"], "--set takes the runs' generation settings, sample.KEY=VALUE; got 'foo=1'")])
@pytest.mark.parametrize("dry_run", [True, False])
def test_sweep_run_refuses_bad_numbers_and_settings_before_anything(tmp_path, capsys, flags, words, dry_run):
    f = tmp_path / "s.py"
    f.write_text(SWEEP_FILE)
    argv = ["sweep", "run", str(f), "--out", str(tmp_path / "out"), "--data", str(tmp_path), *flags]
    assert main(argv + (["--dry-run"] if dry_run else [])) == 2
    cap = capsys.readouterr()
    assert (cap.err.strip(), cap.out) == (f"handx sweep run: error: {words}", "")
    assert not (tmp_path / "out").exists()


def test_sweep_run_without_data_is_exit_2(tmp_path, capsys):
    f = tmp_path / "s.py"
    f.write_text(SWEEP_FILE)
    assert main(["sweep", "run", str(f), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip() == "handx sweep run: error: --data (and --encoder for these runs) are required"
    assert not (tmp_path / "out").exists()


def test_a_sweep_json_or_status_json_that_is_a_list_is_one_line_naming_it(tmp_path, capsys):
    f = tmp_path / "s.py"
    f.write_text(SWEEP_FILE)
    out = tmp_path / "out"
    out.mkdir()
    (out / "sweep.json").write_text("[]")
    assert main(["sweep", "run", str(f), "--out", str(out), "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"handx sweep run: error: file {out / 'sweep.json'}: expected an object") and "\n" not in err
    assert (out / "sweep.json").read_text() == "[]" and not (out / "runs").exists()  # nothing run, nothing rewritten
    (out / "sweep.json").unlink()
    assert main(["sweep", "run", str(f), "--out", str(out), "--data", str(tmp_path)]) == 0
    capsys.readouterr()
    (out / "runs" / "a" / "train_done.json").unlink()  # an unfinished run: its status.json is read
    (out / "runs" / "a" / "status.json").write_text("[]")
    assert main(["sweep", "status", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"handx sweep status: error: file {out / 'runs/a/status.json'}: expected an object"), err


def test_a_finished_sweep_scored_on_fewer_prompts_than_its_block_is_not_rescored(tmp_path, monkeypatch, capsys):
    """--eval-limit 16 at block 32: the evaluator scores the 16 prompts as one block of 16 (and says so in
    eval.json); relaunching the finished sweep as it is does nothing and says so, and writes no
    eval.<id>.b16.N.json."""
    from test_sweeps import _fake_evaluator, _fake_handx_stages, cfg_for, fake

    from handx_jax.evaluation import evaluator_id
    from sweeps.launcher import launch, status

    def on_stage(stage, argv):
        if stage == "generate":
            Path(argv[argv.index("--out") + 1]).write_bytes(b"samples")
            return "generate"
        E, block = argv[argv.index("--evaluator") + 1], int(argv[argv.index("--block") + 1])
        prompts = 16  # what --eval-limit 16 generated; eval run's block is one block of them (scoring.rprec_block_used)
        (Path(argv[argv.index("--out") + 1]) / "eval.json").write_text(json.dumps(
            {"rprec_top3": 0.2, "_meta": {"evaluator_id": evaluator_id(E), "prompts": prompts,
                                          "rprec_block": min(block, prompts), "rprec_block_requested": block}}))
        return ("evaluate", block)

    calls = _fake_handx_stages(monkeypatch, on_stage)
    (tmp_path / "data").mkdir()
    E = _fake_evaluator(tmp_path / "E")
    cfg = cfg_for(tmp_path, evaluator=str(E), eval_limit=16)
    assert not launch([fake("a")], cfg).failed and calls == ["train", "generate", ("evaluate", 32)]
    capsys.readouterr()
    for _ in range(2):
        assert not launch([fake("a")], cfg).failed
        assert "1 of 1 run(s) already trained and scored: nothing to do" in capsys.readouterr().out
    run = tmp_path / "sweep" / "runs" / "a"
    assert len(calls) == 3 and sorted(p.name for p in run.glob("eval*.json")) == ["eval.json"]
    assert [r["status"] for r in status(tmp_path / "sweep")] == ["done"]
    # asking for block 16 itself gives the same scores (one block of the 16 prompts): nothing to redo either
    assert not launch([fake("a")], cfg_for(tmp_path, evaluator=str(E), eval_limit=16, rprec_block=16)).failed
    assert len(calls) == 3
    # a block the 16 prompts would be scored at differently (8) is a rescore, the old scores kept
    assert not launch([fake("a")], cfg_for(tmp_path, evaluator=str(E), eval_limit=16, rprec_block=8)).failed
    assert calls[3:] == [("evaluate", 8)] and (run / f"eval.{evaluator_id(E)}.b16.json").exists()
