import os
import shutil
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("WANDB_MODE", "disabled")
os.environ.setdefault("MPLBACKEND", "Agg")

# One scratch folder for the whole session, created by the controller before the xdist workers start (they,
# and the CLI subprocesses the tests start, inherit the variables) and removed at the end:
# - jax_cache/: a persistent XLA compilation cache. Many tests train, resume or generate with the same tiny
#   configs; compiling a tiny denoiser's train step costs 10-20 s of CPU here, loading it from the cache
#   milliseconds. A user's own JAX_COMPILATION_CACHE_DIR is kept.
# - shared/: read-only fixtures built once per session and copied by the tests that need them
#   (tests/diffusion_fixtures.py: the 32-clip corpus with its text cache).
_SESSION = None
if "PYTEST_XDIST_WORKER" not in os.environ and "HANDX_TEST_SESSION" not in os.environ:
    _SESSION = tempfile.mkdtemp(prefix="handx-test-session-")
    os.environ["HANDX_TEST_SESSION"] = _SESSION
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.join(_SESSION, "jax_cache"))


def pytest_unconfigure(config):
    if _SESSION and not hasattr(config, "workerinput"):
        shutil.rmtree(_SESSION, ignore_errors=True)
