"""constraints.txt (``make lock``, tools/lock.py): the versions ``make`` installs by default."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib", reason="Python < 3.11 has no tomllib to read pyproject.toml")

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))

from lock import canonical, closure, render  # noqa: E402


def _pins(text: str) -> dict[str, str]:
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    pins = dict(re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)==([^=\s;]+)", ln).groups() for ln in lines)
    assert len(pins) == len(lines), "every line of constraints.txt is NAME==VERSION"
    return pins


def test_constraints_pin_every_declared_dependency_exactly():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {canonical(re.match(r"[A-Za-z0-9._-]+", r).group())
                for r in (*project["dependencies"], *project["optional-dependencies"]["dev"])}
    pins = _pins((ROOT / "constraints.txt").read_text())
    assert declared - set(pins) == set(), "a dependency of pyproject.toml is not pinned"
    # what a run's provenance names, and what decides its numbers, is pinned too (jaxlib comes with jax)
    assert {"jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "numpy"} <= set(pins)
    assert "handx-jax" not in pins  # the clone itself is installed editable


def test_lock_writes_the_requirement_closure_not_the_whole_environment(tmp_path):
    from importlib import metadata

    pins = closure()
    assert pins["jax"] == metadata.version("jax") and pins["jaxlib"] == metadata.version("jaxlib")
    assert pins["ml-dtypes"] == metadata.version("ml_dtypes")  # indirect: jax -> ml_dtypes
    assert pins["pytest"] == metadata.version("pytest")  # the dev extra
    assert "pip" not in pins and "handx-jax" not in pins  # installed, but nothing requires them
    assert _pins(render(pins)) == pins
    r = subprocess.run([sys.executable, str(ROOT / "tools/lock.py"), "-o", str(tmp_path / "c.txt")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert _pins((tmp_path / "c.txt").read_text()) == pins


def test_make_installs_with_the_constraints_unless_emptied():
    def pip_line(*args):
        out = subprocess.run(["make", "-n", "-B", "-C", str(ROOT), "venv", *args], capture_output=True, text=True)
        assert out.returncode == 0, out.stderr
        return next(ln for ln in out.stdout.splitlines() if "pip install" in ln and "-e" in ln)

    assert "-c constraints.txt -e '.[dev]'" in pip_line()
    assert "-c" not in pip_line("CONSTRAINTS=").split()
