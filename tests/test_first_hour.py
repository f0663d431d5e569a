"""The README's first hour is a test (issue 51 item 2): the block between ``<!-- first-hour:begin -->`` and
``<!-- first-hour:end -->`` runs as written, in a temporary folder, with only its size and step variables set
tiny (the README says so). It is plain shell: ``NAME=${NAME:-default}`` and ``NAME=value`` assignments,
comments, ``\\`` continuations and ``handx …`` commands; anything else fails the test, so what runs here is
what a user pastes, read as bash reads it. Every command runs in one child process
(``python tests/test_first_hour.py``, which calls ``handx_jax.cli.main``, the ``handx`` entry point, once per
command), so the block pays for Python's and JAX's imports once; the sweep's stages are the launcher's own
subprocesses.

Why a child, and why LLVM -O0 there: at two steps per model, the block's cost is XLA compiling some 14
training, sampling and scoring programs (about 200 CPU-s of the suite, the largest test), not running them.
The session compiles at ``--xla_backend_optimization_level=1`` (tests/conftest.py) because some tests run
hundreds of steps; a process's XLA flags are fixed when its backend starts, so the block gets a process of its
own with level 0, which compiled the same block in 164 CPU-s instead of 203 (2026-12-02, one process, cold
cache). The maths is the same (no fast-math); only the generated code is slower, which two steps do not feel.

This one test covers: ``handx data synth`` with no recipe flags builds a prefix of the standard corpus
(``handx standard check`` says so; issue 51 item 3); one model of each family trains, samples and is scored
by the packaged evaluator; and ``handx sweep run --evaluator standard`` runs a real tiny sweep (item 5).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
BEGIN, END = "<!-- first-hour:begin -->", "<!-- first-hour:end -->"
# The only values the test changes: sizes and step counts (the README's first line of the block).
TINY = {"CLIPS": "130", "STEPS": "2", "SWEEP_STEPS": "2", "PROMPTS": "8", "DDIM": "2"}
_ASSIGN = re.compile(r"^([A-Z_][A-Z0-9_]*)=(.*)$")
_VAR = re.compile(r"\$\{([A-Z_][A-Z0-9_]*)(?::-([^}]*))?\}|\$([A-Z_][A-Z0-9_]*)")


def first_hour_lines(readme: Path = REPO / "README.md") -> list[str]:
    """The block's logical lines (continuations joined), without the code fence."""
    text = readme.read_text()
    assert text.count(BEGIN) == 1 and text.count(END) == 1, "the README marks one first-hour block"
    body = text.split(BEGIN, 1)[1].split(END, 1)[0].strip()
    assert body.startswith("```bash\n") and body.endswith("\n```"), "the block is one ```bash fence"
    return body[len("```bash\n"):-len("\n```")].replace("\\\n", " ").splitlines()


def expand(word: str, env: dict) -> str:
    """``$X``, ``${X}`` and ``${X:-default}`` as the shell expands them (unset or empty: the default)."""
    def sub(m):
        name = m.group(1) or m.group(3)
        if name not in env and m.group(2) is None:
            raise AssertionError(f"the first hour uses ${name} before setting it")
        return env.get(name) or (m.group(2) or "")
    return _VAR.sub(sub, word)


def parse(lines: list[str], overrides: dict) -> list[list[str]]:
    """The block's ``handx`` commands as argv lists, its assignments applied in order (``overrides`` play the
    environment a user sets before pasting)."""
    env, commands = dict(overrides), []
    for line in lines:
        words = shlex.split(line, comments=True)
        if not words:
            continue
        if all(_ASSIGN.match(w) for w in words):
            for w in words:
                name, value = _ASSIGN.match(w).groups()
                env[name] = expand(value, env)
            continue
        assert words[0] == "handx", f"the first hour runs only handx commands and assignments: {line!r}"
        commands.append([expand(w, env) for w in words[1:]])
    return commands


def test_the_first_hour_parses_and_its_first_line_holds_every_size():
    lines = first_hour_lines()
    first = shlex.split(lines[0], comments=True)
    assert {_ASSIGN.match(w).group(1) for w in first} == set(TINY)  # the variables this test sets, and no other
    assert all(re.fullmatch(r"\$\{(\w+):-\d+\}", _ASSIGN.match(w).group(2)) for w in first)  # each a number
    commands = parse(lines, {})
    verbs = [" ".join(c[:2]) for c in commands]
    for need in ("data synth", "standard check", "train diffusion", "train tokenizer", "train ar", "train ghtt-pose",
                 "train ghtt", "eval run", "eval prediction", "eval recognition", "sweep run", "analyze fit"):
        assert need in verbs, need
    synth = commands[verbs.index("data synth")]
    assert not {"--annotation", "--motion", "--seed"} & set(synth)  # the defaults are the standard recipe
    sweep = commands[verbs.index("sweep run")]
    assert sweep[sweep.index("--evaluator") + 1] == "standard"
    # a shell reads the block the same way: the tiny sizes reach every command that takes one
    tiny = parse(lines, TINY)
    assert tiny[0][tiny[0].index("--clips") + 1] == "130" and all("1500" not in c for c in tiny)


def test_the_readme_reads_as_a_guide():
    """Issue 51 item 1: about 150-200 lines, none over 120 characters, history in docs/HISTORY.md."""
    lines = (REPO / "README.md").read_text().splitlines()
    long = [f"line {i}: {len(x)} characters" for i, x in enumerate(lines, 1) if len(x) > 120]
    assert not long, long
    assert 100 <= len(lines) <= 220, len(lines)
    assert (REPO / "docs/HISTORY.md").exists() and "docs/HISTORY.md" in "\n".join(lines)


def run_block(workdir: Path, log: Path) -> None:
    """The child's side: every command of the block, in order, in ``workdir``; one JSON line per command
    (argv, exit code, what it printed on stdout) appended to ``log``, stopping at the first that fails."""
    import contextlib
    import io

    from handx_jax.cli import main

    os.chdir(workdir)
    for argv in parse(first_hour_lines(), TINY):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            rc = main(argv)
        with open(log, "a") as f:
            f.write(json.dumps({"argv": argv, "rc": rc, "out": out.getvalue()}) + "\n")
        if rc != 0:
            return


def level0(flags: str) -> str:
    """``XLA_FLAGS`` with LLVM -O0 in place of the session's level, for processes that only compile and run a
    few steps (this block's child; test_ghtt's sweep stages)."""
    flags = re.sub(r"--xla_backend_optimization_level=\d+", "", flags)
    return (flags + " --xla_backend_optimization_level=0").strip()


@pytest.mark.e2e
def test_the_first_hour_runs_as_written(tmp_path):
    from handx_jax import standard
    from handx_jax.evaluation import evaluator_id

    # The block's relative paths are the clone's: the package's encoder and the sweep files.
    for name in ("handx_jax", "sweeps"):
        (tmp_path / name).symlink_to(REPO / name)
    log = tmp_path / "commands.jsonl"
    # The session's compilation cache (tests/conftest.py), so that the block's scoring programs compiled by its
    # `eval run` serve the sweep's evaluate stages and other -O0 tests' (tests/test_ghtt.py's sweep); the XLA
    # flags are part of the cache key, so -O0 and the session's level never mix. A user who names no cache (the
    # sweep's stages then share OUT/jax_cache) is tests/test_sweeps.py's.
    env = dict(os.environ)
    env.update(HANDX_CACHE_DIR=str(tmp_path / "cache"), XLA_FLAGS=level0(os.environ.get("XLA_FLAGS", "")))
    p = subprocess.run([sys.executable, __file__, str(tmp_path), str(log)], env=env, capture_output=True, text=True)
    done = [json.loads(x) for x in log.read_text().splitlines()] if log.exists() else []
    failed = [d for d in done if d["rc"] != 0]
    assert p.returncode == 0 and not failed, \
        f"handx {' '.join((failed or done or [{'argv': ['?']}])[-1]['argv'])}: {p.stderr[-3000:]}"
    assert [d["argv"] for d in done] == parse(first_hour_lines(), TINY)  # every command ran, in order
    (check,) = [d for d in done if d["argv"][:2] == ["standard", "check"]]
    # `handx data synth` without recipe flags: a standard prefix
    assert "a prefix of the standard corpus, 130 clips" in check["out"]
    R, v8 = tmp_path / "runs/first-hour", evaluator_id(standard.evaluator_dir())
    for run in ("diffusion", "ar"):  # sampled and scored by the packaged evaluator, 4 samples of every prompt
        e = json.loads((R / run / "eval.json").read_text())
        assert (e["_meta"]["evaluator_id"], e["_meta"]["evaluator_name"]) == (v8, f"standard-v{standard.VERSION}")
        assert e["_meta"]["groups"] == 4 and 0 <= e["rprec_top1"] <= e["rprec_top3"] <= 1
    pred = json.loads((R / "ghtt/eval_prediction.json").read_text())
    assert pred["_meta"]["observed_frames"] == 16 and pred["observed"]["max_joint_error_mm"] < 1.0
    rec = json.loads((R / "ghtt/eval_recognition.json").read_text())
    assert 0 <= rec["run"]["rprec_top3"]["mean"] <= 1
    rows = [json.loads(x) for x in (R / "sweep/results.jsonl").read_text().splitlines()]
    assert len(rows) == 3 and {r["evaluator_id"] for r in rows} == {v8}  # `--evaluator standard`: the packaged one
    assert all(0 <= r["rprec_top1"] <= r["rprec_top3"] <= 1 for r in rows)
    # Each row reads its run's config.json and model: sizes, the whole train split drawn as clips (the
    # default sampling), parameters, and both FLOPs conventions (the paper's counts the text encoder too).
    assert sorted((r["layers"], r["dim"]) for r in rows) == [(1, 32), (2, 64), (2, 128)]
    assert all(r["data_fraction"] == 1.0 and r["data_sampling"] == "clips" for r in rows)
    assert all(r["params"] > 0 and r["flops_per_sample_paper"] > r["flops_per_sample"] > 0 for r in rows)
    by_dim = sorted(rows, key=lambda r: r["dim"])
    assert [r["params"] for r in by_dim] == sorted({r["params"] for r in rows})  # wider: more parameters
    # Scored at the block its prompts allow: 8 tiny prompts give block 8, which the launcher records as the block
    # chosen, so the runs are done and a relaunch would not rescore them (issue 54 item 5); the README's 256
    # prompts on 4,000 clips give 32.
    assert {(r["rprec_block"], r["status"]) for r in rows} == {(8, "done")}
    assert (R / "sweep/fit.png").stat().st_size > 0 and os.path.exists(R / "sweep/results.csv")


if __name__ == "__main__":  # the child process of test_the_first_hour_runs_as_written
    run_block(Path(sys.argv[1]), Path(sys.argv[2]))
