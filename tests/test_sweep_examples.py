"""Every example command in a ``sweeps/*.py`` docstring runs (issue 51 item 2), with its placeholders (``D``,
``E``, ``S``, …) filled in.

- ``handx sweep run …`` examples run with ``--dry-run``: their preset's runs and the evaluator they name are
  checked (``--evaluator standard`` resolves: it used to become ``<cwd>/standard``), and nothing trains. Their
  real runs are other tests': ``sweeps/diffusion_cpu_study.py`` (demo preset, ``--evaluator standard``) is
  tests/test_first_hour.py's sweep; ``sweeps/ar_size_codebook.py`` tests/test_ar_sweep.py (the cpu preset's two
  smallest LMs); ``sweeps/ghtt_cpu_study.py`` tests/test_ghtt.py::test_real_tiny_ghtt_sweep_scored_on_prediction
  (the tiny preset); ``sweeps/diffusion_depth_data.py``'s paper preset needs a GPU, and its stages are every
  diffusion sweep's (tests/test_sweeps.py::test_a_real_diffusion_run_and_its_row).
- ``handx analyze fit …`` examples run for real on the committed results of the sweep the docstring launches.
- ``handx text cache …`` runs in the README's first hour (tests/test_first_hour.py), the same command; the
  stage lists (``STEP``, ``RUN`` placeholders) are what the real sweep tests run as stages.
"""

from __future__ import annotations

import ast
import json
import re
import shlex
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SWEEPS = sorted(p for p in (REPO / "sweeps").glob("*.py") if p.name != "__init__.py")
# Where a docstring's command writes or reads, and what it reads from the committed results.
COMMITTED = {"sweeps/diffusion_cpu_study.py": "docs/results/cpu_study/v8/results.csv",
             "sweeps/ghtt_cpu_study.py": "docs/results/ghtt/sweep_results.csv",
             "sweeps/bimart_cpu_study.py": "docs/results/bimart/size_sweep/results.csv"}


def examples(path: Path) -> list[list[str]]:
    """The ``handx …`` command lines of a module docstring (continuations joined), as argv after ``handx``."""
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    lines = doc.replace("\\\n", " ").splitlines()
    return [shlex.split(re.sub(r"\s{2,}\(step [^)]*\)$", "", line.strip()))[1:]
            for line in lines if line.strip().startswith("handx ")]


def test_the_sweep_files_with_examples_are_the_ones_named_here():
    have = {str(p.relative_to(REPO)) for p in SWEEPS if any(c[:2] == ["sweep", "run"] for c in examples(p))}
    assert have == {"sweeps/diffusion_cpu_study.py", "sweeps/ar_size_codebook.py", "sweeps/ghtt_cpu_study.py",
                    "sweeps/diffusion_depth_data.py", "sweeps/bimart_cpu_study.py"}


@pytest.mark.parametrize("path", [p for p in SWEEPS if any(c[:2] == ["sweep", "run"] for c in examples(p))],
                         ids=lambda p: p.name)
def test_sweep_run_examples_dry_run(path, tmp_path, monkeypatch, capsys):
    from handx_jax import standard
    from handx_jax.cli import main
    from sweeps.launcher import load_sweep

    monkeypatch.chdir(REPO)
    fill = {"D": str(tmp_path / "data"), "DATA": str(tmp_path / "data"), "E": str(standard.encoder_dir()),
            "ENC": str(standard.encoder_dir()), "V": "standard", "S": str(tmp_path / "sweep"),
            "OUT": str(tmp_path / "sweep")}
    for argv in examples(path):
        if argv[:2] != ["sweep", "run"]:
            continue
        argv = [fill.get(a, a) for a in argv]
        argv = [str(tmp_path / "sweep") if a.startswith("runs/") else a for a in argv]
        # every example of a text family scores on the yardstick; BimArt's (object2motion) reads no text evaluator
        assert argv[argv.index("--evaluator") + 1] == "standard" if "--evaluator" in argv else "bimart" in path.name
        capsys.readouterr()
        assert main([*argv, "--dry-run"]) == 0, capsys.readouterr().err
        printed = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
        preset = argv[argv.index("--preset") + 1]
        want = [s.name for s in load_sweep(str(path.relative_to(REPO)), preset=preset)]
        assert [r["name"] for r in printed if "name" in r] == want and want
        assert not (tmp_path / "sweep").exists()  # a dry run writes nothing


@pytest.mark.parametrize("sweep", sorted(COMMITTED))
def test_analyze_examples_run_on_the_committed_results(sweep, tmp_path, capsys):
    from handx_jax.cli import main

    fits = [c for c in examples(REPO / sweep) if c[:2] == ["analyze", "fit"]]
    assert fits
    for argv in fits:
        argv = [str(REPO / COMMITTED[sweep]) if a.endswith("results.csv") else
                str(tmp_path / "fit.png") if a.endswith("fit.png") else a for a in argv]
        capsys.readouterr()
        assert main(argv) == 0, capsys.readouterr().err
        out = capsys.readouterr().out
        x, y = argv[argv.index("--x") + 1], argv[argv.index("--y") + 1]
        assert y in out and re.search(r"\br\s*=\s*-?\d\.\d+", out), out
        assert (tmp_path / "fit.png").stat().st_size > 0
        assert x in ("compute", "flops")
