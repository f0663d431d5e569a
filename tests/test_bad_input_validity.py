"""Bad input to ``handx standard validity`` (issue 54): every setting is refused before any scoring (a block
too small for top-3 to mean anything, a negative seed, an empty ``--kinds``, a tokenizer that is no run); a
second suite writing the same ``--out`` is refused while the first holds it; and a suite killed with SIGKILL
while it moves its report into place leaves no report that is half of one run (``validity.json``, moved last,
marks a whole report; the next run removes the rest). An 8-clip dataset, caption stability only (no
evaluator); the kill -9 runs a real process."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from handx_jax.cli import main
from handx_jax.validity import suite
from tiny_dataset import write_tiny_dataset

WORKER = Path(__file__).parent / "validity_kill_worker.py"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return write_tiny_dataset(tmp_path_factory.mktemp("tiny") / "D")


def _validity(data, out, *flags):
    return ["standard", "validity", "--data", str(data), "--out", str(out), "--no-evaluator", *map(str, flags)]


def _refused(argv, capsys) -> str:
    try:
        rc = main(argv)
    except SystemExit as e:  # argparse refused a flag while parsing
        rc = e.code
    cap = capsys.readouterr()
    assert rc == 2 and "Traceback" not in cap.err, (rc, cap.err)
    return cap.err.strip().splitlines()[-1]


TOP3 = "(top-3 R-Precision among 3 or fewer candidates is 1 for any motion)"


@pytest.mark.parametrize("flags, words", [
    (["--block", "0"], f"argument --block: must be a whole number >= 4, got '0' {TOP3}"),
    (["--block", "-4"], f"argument --block: must be a whole number >= 4, got '-4' {TOP3}"),
    (["--block", "1"], f"argument --block: must be a whole number >= 4, got '1' {TOP3}"),
    (["--seed", "-1"], "argument --seed: must be a whole number >= 0, got '-1'"),
    (["--limit", "1"], "argument --limit: must be a whole number >= 2, got '1' (another clip's motion needs two clips)"),
    (["--kinds", ""], "handx: error: --kinds names no perturbation kind; choose from white, lowfreq, offset, shift, "
                      "reverse, other, swap_hands, swap_fingers, still_fingers (or leave --kinds out for all of them)"),
    (["--kinds", " , "], "--kinds names no perturbation kind"),
    (["--kinds", "white,wobble"], "handx: error: --kinds wobble: unknown; choose from white"),
])
def test_a_bad_setting_is_refused_before_any_scoring(tiny, tmp_path, capsys, flags, words):
    assert words in _refused(_validity(tiny, tmp_path / "V", *flags), capsys)
    assert list(tmp_path.iterdir()) == []


def test_the_settings_are_checked_through_the_api_too(tiny, tmp_path):
    from handx_jax.config import ConfigError

    with pytest.raises(ConfigError, match=r"--block must be a whole number >= 4, got 3 \(top-3"):
        suite.run(str(tiny), str(tmp_path / "V"), evaluator=None, block=3)
    with pytest.raises(ConfigError, match="--seed must be a whole number >= 0, got -1"):
        suite.run(str(tiny), str(tmp_path / "V"), evaluator=None, seed=-1)
    assert list(tmp_path.iterdir()) == []


def test_a_bad_tokenizer_is_refused_before_the_suite_runs(tiny, tmp_path, capsys):
    err = _refused(_validity(tiny, tmp_path / "V", "--tokenizer", tmp_path / "BAD"), capsys)
    assert err == f"handx: error: file {tmp_path / 'BAD'}: not a run folder (no config.json)"
    assert list(tmp_path.iterdir()) == []


def test_out_inside_the_dataset_is_refused(tiny, capsys):
    err = _refused(_validity(tiny, tiny / "V"), capsys)
    assert err == f"handx: error: --out {tiny / 'V'} is inside the dataset it reads, --data {tiny}; choose another " \
                  "--out outside it"
    assert not (tiny / "V").exists()


def test_a_second_suite_on_one_out_is_refused(tiny, tmp_path, capsys):
    out = tmp_path / "V"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time\nfrom handx_jax.infra.runlock import RunLock\n"
                               "RunLock.for_output(sys.argv[1]).acquire()\nprint('held', flush=True)\ntime.sleep(60)",
                               str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        err = _refused(_validity(tiny, out, "--kinds", "shift"), capsys)
        assert err.startswith(f"handx: error: {out} is in use by pid {holder.pid} on "), err
        assert not out.exists()
    finally:
        holder.kill()
        holder.wait()


def test_a_suite_killed_while_moving_its_report_in_leaves_no_mixed_report(tiny, tmp_path, capsys):
    out = tmp_path / "V"
    (tmp_path / "keep").mkdir()
    assert main(_validity(tiny, out, "--kinds", "shift")) == 0
    first = {n: (out / n).read_bytes() for n in suite.REPORT_FILES}
    (out / "README.md").write_text("a results folder's own file\n")
    report = json.loads(first["validity.json"])
    report["perturbation_seed"] = 7  # another run's report
    (tmp_path / "keep" / "report.json").write_text(json.dumps(report))
    # kill -9 after validity.png is moved in, before validity.md and validity.json: the old report's files are
    # gone (validity.json first), the new json is not there, so no json sits beside another run's md or png
    r = subprocess.run([sys.executable, str(WORKER), str(out), str(tmp_path / "keep" / "report.json"), "1"],
                       capture_output=True, text=True)
    assert r.returncode == -9, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["README.md", "validity.png"]
    assert any(p.name.startswith(".V.") and p.name.endswith(".tmp") for p in tmp_path.iterdir())
    capsys.readouterr()
    assert main(_validity(tiny, out, "--kinds", "shift")) == 0  # the rerun removes what the kill left, then writes
    err = capsys.readouterr().err
    assert f"removed validity.png in {out}: a report without its validity.json" in err
    assert "left by a writer of V that was killed" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["V", "keep"]
    again = json.loads((out / "validity.json").read_text())
    assert {**again, "seconds": 0} == {**json.loads(first["validity.json"]), "seconds": 0}
    assert (out / "validity.md").read_bytes() == first["validity.md"] and (out / "validity.png").is_file()
    assert (out / "README.md").read_text() == "a results folder's own file\n"
