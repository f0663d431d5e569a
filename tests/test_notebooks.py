"""Execute every notebook in notebooks/ so that none of them rots.

Each notebook runs in a fresh kernel started with this interpreter (``sys.executable``, i.e. the
project's venv), in a temporary working directory, with a per-cell timeout; any cell error fails
the test. The kernel is described by a kernelspec written into a temporary JUPYTER_PATH, so the test
does not depend on which kernels happen to be installed on the machine.

quickstart.ipynb trains a diffusion run for a few dozen steps unless HANDX_RUN names one; here it is
given the session's tiny run (tests/diffusion_fixtures.make_run, trained once per session and shared with
test_diffusion_train.py and test_generate.py), so the kernel does not compile a second training program.
What that skips is two calls the suite runs elsewhere as they are: ``text.cache.build_cache(data, encoder)``
(test_text_cache.py) and ``families.diffusion.train(run_dir, make_config("tiny", overrides, data=...,
encoder=...))`` (test_diffusion_train.py); the notebook's ``make_config`` call with its overrides still
runs (unknown keys and bad values fail the cell), and so does everything after it: sampling, the animation
and the standard evaluator's scores of the test prompts. data_exploration.ipynb is given the session's
32-clip corpus (tests/diffusion_fixtures.make_dataset, the one that run trained on) as HANDX_DATA, so its
kernel does not synthesise a corpus of its own (``build_corpus``, the cell's fallback, is what
test_dataset_build.py tests); every cell after it runs on that corpus.
"""

import json
import os
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

REPO = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((REPO / "notebooks").glob("*.ipynb"))
KERNEL = "handx-test-python"
CELL_TIMEOUT_S = 600


@pytest.fixture()
def kernel_env(tmp_path, monkeypatch):
    spec_dir = tmp_path / "jupyter" / "kernels" / KERNEL
    spec_dir.mkdir(parents=True)
    (spec_dir / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "handx-jax test kernel",
        "language": "python",
    }))
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter") + os.pathsep + os.environ.get("JUPYTER_PATH", ""))
    monkeypatch.setenv("IPYTHONDIR", str(tmp_path / "ipython"))
    monkeypatch.setenv("PYTHONPATH", str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    monkeypatch.setenv("JAX_PLATFORMS", os.environ.get("JAX_PLATFORMS", "cpu"))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("HANDX_CACHE_DIR", str(tmp_path / "handx-cache"))  # the standard evaluator's reference cache
    work = tmp_path / "work"
    work.mkdir()
    return work


def _session_run(root: Path) -> dict[str, str]:
    from diffusion_fixtures import make_run

    return {"HANDX_RUN": str(make_run(root)[1])}


def _session_data(root: Path) -> dict[str, str]:
    from diffusion_fixtures import make_dataset

    return {"HANDX_DATA": str(make_dataset(root))}


# Environment a notebook runs with, beyond kernel_env's (see the module docstring).
NOTEBOOK_ENV = {"quickstart.ipynb": _session_run, "data_exploration.ipynb": _session_data}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_executes(path, kernel_env, tmp_path, monkeypatch):
    if path.name in NOTEBOOK_ENV:
        for k, v in NOTEBOOK_ENV[path.name](tmp_path / "fixtures").items():
            monkeypatch.setenv(k, v)
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    client = nbclient.NotebookClient(nb, timeout=CELL_TIMEOUT_S, kernel_name=KERNEL,
                                     resources={"metadata": {"path": str(kernel_env)}})
    try:
        client.execute()
    except nbclient.exceptions.CellExecutionError as e:
        pytest.fail(f"{path.name}: a cell failed\n{e}")
