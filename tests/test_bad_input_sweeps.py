"""Bad input to ``handx sweep`` (issue 31 items 5, 6): a sweep file is validated when it is loaded, so
a ``runs()`` that raises, returns None or nothing, a syntax error or duplicate run ids are one line
naming the file (exit 2, no traceback, no sweep folder made); ``sweep status`` on a corrupt
``sweep.json`` says it is corrupt, not that there is none. In-process, no training: milliseconds."""

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
