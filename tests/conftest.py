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
# - XLA's backend optimisation level 1 (LLVM's -O1 instead of XLA's default, higher) for every program compiled in the
#   session, and the compilation cache for compilations of any length (JAX's default caches only those over
#   1 s). The suite's CPU goes mostly to XLA compiling tiny models' programs that then run a few steps: a
#   tiny denoiser's 4-step training took 23 CPU-s at level 1 instead of 31, with the same execution speed
#   (the 200-step tokenizer fit of test_fsq.py runs in 9.3 CPU-s at level 1 and at the default). Level 0
#   compiles faster still but runs 10x slower (that fit: 104 CPU-s). The maths is the same (no fast-math;
#   float rounding may differ in the last bits). A user's own XLA_FLAGS level is kept.
# - one CPU device in every process of the session: the tests' own processes have one anyway (JAX's
#   default), and the `handx` subprocesses (CLI tests, sweep stages, notebook kernels) would otherwise
#   configure one per core (handx_jax.infra.hostdevices). The compilation cache's key includes the device count
#   (not the flag), so with one count everywhere a program compiled in a test process serves a sweep stage
#   and the reverse (the evaluator's metric programs, a tiny tokenizer's or denoiser's training step).
#   tests/test_hostdevices.py removes the flag and checks the several-device path itself.
# - shared/: read-only fixtures built once per session and copied by the tests that need them
#   (tests/diffusion_fixtures.py: the 32-clip corpus with its text cache).
_SESSION = None
if "PYTEST_XDIST_WORKER" not in os.environ and "HANDX_TEST_SESSION" not in os.environ:
    _SESSION = tempfile.mkdtemp(prefix="handx-test-session-")
    os.environ["HANDX_TEST_SESSION"] = _SESSION
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.join(_SESSION, "jax_cache"))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=1").strip()
    if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", "") and \
            "JAX_NUM_CPU_DEVICES" not in os.environ:
        os.environ["XLA_FLAGS"] += " --xla_force_host_platform_device_count=1"


def pytest_unconfigure(config):
    if _SESSION and not hasattr(config, "workerinput"):
        shutil.rmtree(_SESSION, ignore_errors=True)


# Longest files first (worker-seconds of one quiet 2-worker run, 2026-11-24): with `--dist loadfile` each file
# runs whole on one worker, and a heavy file started last runs alone at the end while the other core idles.
# Starting the longest ones first is the classic longest-processing-time schedule; files not listed keep
# their order after these. xdist (>= 3.6) would re-sort the files by their number of tests instead
# (--loadscope-reorder, its default); pytest_configure turns that off for every invocation of this suite. test_slurm.py leads: on a fresh machine it first apt-installs slurm,
# munge and mariadb (~30 s, mostly waiting on the network and the disk), and its jobs run outside the
# worker, so its waiting overlaps the other worker's compute.
HEAVY_FIRST = ("test_first_hour.py", "test_slurm.py", "test_ghtt.py", "test_object_corpus.py", "test_ar_sweep.py", "test_validity.py", "test_evaluation.py",
               "test_generate.py", "test_notebooks.py", "test_prediction.py", "test_reverse.py",
               "test_ar_family.py", "test_sweeps.py", "test_diffusion_train.py", "test_dit.py",
               "test_dataset_build.py", "test_text_cache.py", "test_prefix_lm.py", "test_standard.py", "test_fsq.py",
               "test_diffusion_sampler.py", "test_text_pretrain.py", "test_family_registry.py", "test_bimart.py", "test_interop.py",
               "test_train.py", "test_text_t5.py", "test_metrics.py", "test_perf_paths.py", "test_benchmarks.py",
               "test_distributed.py")


def pytest_configure(config):
    if hasattr(config.option, "loadscopereorder"):  # pytest-xdist present: keep HEAVY_FIRST's order
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(session, config, items):
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(HEAVY_FIRST)))  # stable: order within a file kept
