# The README's two set-up commands: `make demo` and `make test`.
# Each creates (or refreshes) .venv and installs the package with its dev extras.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DEMO_DIR ?= runs/demo
STANDARD_WORK ?= runs/standard-build
# The versions the suite last passed with (tools/lock.py; `make lock` rewrites it from .venv). Every install
# below uses them; `make test CONSTRAINTS=` installs the newest versions pyproject.toml allows instead.
CONSTRAINTS ?= constraints.txt
UV_VERSION ?= 0.13.9

.PHONY: venv demo sweep-cpu sweep-ar-cpu test test-e2e lock bench standard-assets standard-assets-v8 clean

# uv (a pinned installer, pip's drop-in) resolves, downloads and byte-compiles in parallel: 21 s here from
# a cold cache, where pip + compileall took 47 s, for the same versions (constraints.txt). It is only the
# installer; nothing imports it. Where it cannot be had or fails (no PyPI, another platform), pip does the
# same install. Byte-compile everything either way: where PYTHONDONTWRITEBYTECODE is set (as on this
# project's machines) nothing writes .pyc later, and every Python process (test workers, CLI subprocesses,
# sweep stages, notebook kernels) would compile jax & co. from source on import: 5.5 s instead of 1.6 s.
$(STAMP): pyproject.toml $(CONSTRAINTS)
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	if $(BIN)/python -m pip install -q uv==$(UV_VERSION) 2>/dev/null && \
	    $(BIN)/uv pip install -q --compile-bytecode --python $(BIN)/python $(if $(CONSTRAINTS),-c $(CONSTRAINTS)) -e '.[dev]'; \
	then :; else \
	    echo "make: installing with pip instead of uv (about a minute)"; \
	    $(BIN)/python -m pip install -q --upgrade pip && \
	    $(BIN)/python -m pip install -q --no-compile $(if $(CONSTRAINTS),-c $(CONSTRAINTS)) -e '.[dev]' && \
	    { $(BIN)/python -m compileall -qq -j 0 $(VENV)/lib > /dev/null || true; }; \
	fi
	touch $(STAMP)

venv: $(STAMP)

# After upgrading a package in .venv (or installing with CONSTRAINTS=) and seeing `make test` pass: pin what is
# installed now, the requirement closure of handx-jax[dev] only (tools/lock.py), and commit constraints.txt.
lock: $(STAMP)
	$(BIN)/python tools/lock.py -o constraints.txt
	touch $(STAMP)  # .venv is what constraints.txt now says: no reinstall on the next make

demo: $(STAMP)
	JAX_PLATFORMS=cpu $(BIN)/python -m handx_jax.demo --out $(DEMO_DIR)

# The CPU scaling study (sweeps/diffusion_cpu_study.py, issue 13 item 7): a prefix of the standard corpus and
# its text cache (built once, reused), 6 diffusion runs (3 sizes x 2 data fractions at fixed epochs, steps
# growing with model size: the 'matched' preset; two at a time), each scored by the packaged standard
# evaluator, then the table and the fit of top-3 R-Precision against training compute with its plot.
# 21 min on 2 quiet CPU cores (docs/results/cpu_study/README.md). SWEEP_CPU_PRESET=cpu: the same grid with
# the same steps for every size (the first design, 15-18 min). SWEEP_CPU_SEEDS=[42,1,2]: every configuration
# once per training seed (~20 min per seed), and the fit is on the means over seeds (--mean-replicates); one
# seed's fit moves a lot (r 0.95, 0.77 and 0.96 for three seeds of the same six configurations; 0.92 on their
# means).
SWEEP_CPU_PRESET ?= matched
SWEEP_CPU_SEEDS ?= 42
SWEEP_CPU_DIR ?= runs/sweep-cpu
SWEEP_CPU_CLIPS ?= 4000
SWEEP_CPU_ARGS ?= --eval-limit 10000 --eval-samples 4 --set sample.steps=25 --max-parallel 2
sweep-cpu: $(STAMP)
	@start=$$(date +%s); set -e; export JAX_PLATFORMS=cpu WANDB_MODE=disabled; \
	H="$(BIN)/python -m handx_jax"; D=$(SWEEP_CPU_DIR)/data; \
	ENC=$$($(BIN)/python -c "from handx_jax import standard; print(standard.encoder_dir())"); \
	EV=$$($(BIN)/python -c "from handx_jax import standard; print(standard.evaluator_dir())"); \
	test -f $$D/meta.json || $$H standard corpus --clips $(SWEEP_CPU_CLIPS) --out $$D --quiet; \
	$$H text cache --data $$D --encoder $$ENC; \
	$$H sweep run sweeps/diffusion_cpu_study.py --preset $(SWEEP_CPU_PRESET) --data $$D --encoder $$ENC --evaluator $$EV \
	    --arg 'seeds=$(SWEEP_CPU_SEEDS)' $(SWEEP_CPU_ARGS) --out $(SWEEP_CPU_DIR)/sweep; \
	$$H analyze table $(SWEEP_CPU_DIR)/sweep/results.csv; \
	$$H analyze fit $(SWEEP_CPU_DIR)/sweep/results.csv --x compute --y rprec_top3 --mean-replicates \
	    --plot $(SWEEP_CPU_DIR)/sweep/fit.png | tee $(SWEEP_CPU_DIR)/sweep/fit.txt; \
	$$H analyze fit $(SWEEP_CPU_DIR)/sweep/results.csv --x compute --y rprec_top3 --mean-replicates --json \
	    > $(SWEEP_CPU_DIR)/sweep/fit.json; \
	echo "sweep-cpu finished in $$(( $$(date +%s) - start )) s (corpus prefix, text cache, runs, fit)"

# The AR CPU study (sweeps/ar_size_codebook.py --preset cpu, issue 30 item 5): the codebook axis end to end on
# 2 cores. A prefix of the standard corpus, 3 LM sizes x 3 codebooks (one tokenizer per codebook, shared by
# the three LMs; the joined text cache is the sweep's shared step), two runs at a time, each scored by the
# packaged standard evaluator (4 sampled generations per test prompt), then Table 3, the fit of top-3
# against per-sample FLOPs (the paper's axis) and against training compute, and the factors LM size vs
# codebook. docs/results/ar_cpu_study/README.md has the measured wall time and what the axis shows.
SWEEP_AR_CPU_DIR ?= runs/sweep-ar-cpu
SWEEP_AR_CPU_CLIPS ?= 4000
SWEEP_AR_CPU_ARGS ?= --eval-limit 10000 --eval-samples 4 --max-parallel 2
sweep-ar-cpu: $(STAMP)
	@start=$$(date +%s); set -e; export JAX_PLATFORMS=cpu WANDB_MODE=disabled; \
	H="$(BIN)/python -m handx_jax"; D=$(SWEEP_AR_CPU_DIR)/data; S=$(SWEEP_AR_CPU_DIR)/sweep; \
	ENC=$$($(BIN)/python -c "from handx_jax import standard; print(standard.encoder_dir())"); \
	EV=$$($(BIN)/python -c "from handx_jax import standard; print(standard.evaluator_dir())"); \
	test -f $$D/meta.json || $$H standard corpus --clips $(SWEEP_AR_CPU_CLIPS) --out $$D --quiet; \
	$$H sweep run sweeps/ar_size_codebook.py --preset cpu --data $$D --encoder $$ENC --evaluator $$EV \
	    $(SWEEP_AR_CPU_ARGS) --out $$S; \
	$$H analyze table $$S/results.csv --layout table3 | tee $$S/table3.md; \
	$$H analyze fit $$S/results.csv --x flops --y rprec_top3 --plot $$S/fit.png | tee $$S/fit.txt; \
	$$H analyze fit $$S/results.csv --x flops --y rprec_top3 --json > $$S/fit.json; \
	$$H analyze fit $$S/results.csv --x compute --y rprec_top3 | tee $$S/fit_compute.txt; \
	$$H analyze factors $$S/results.csv --factors flops_analytic,codebook --y rprec_top3 | tee $$S/factors.txt; \
	echo "sweep-ar-cpu finished in $$(( $$(date +%s) - start )) s (corpus prefix, text cache, tokenizers, runs, fits)"

# One pytest worker per core plus one, each test file on one worker (its module fixtures are built once).
# Single-process pytest leaves the second core idle most of the run (wall time ~ user CPU time). With one
# worker per core a core still idled ~80 s of the run: a worker waiting on SLURM jobs, subprocesses or a
# session fixture another worker builds holds its core empty (test_slurm.py alone: 67 s of wall, 14 CPU-s).
# On 2 cores, 3 workers ran pytest in 391 s where 2 took 452 s (same clean clone, quiet machine).
# tests/conftest.py runs the longest files first (HEAVY_FIRST).
TEST_WORKERS ?= $(shell echo $$(( $$(nproc 2>/dev/null || echo 1) + 1 )))
#
# Two tiers, both run by CI (.ci/run): `make test`, the suite a developer runs before every commit (unit, property,
# CLI and in-process end-to-end tests, and a real diffusion sweep and a third family's sweep through the launcher's
# subprocess stages), and `make test-e2e`, the four tests marked `e2e` (tests/test_first_hour.py's README block,
# the real G-HTT and AR sweeps, the validity command on a standard prefix): 470 of the suite's 1,280 CPU-s, each
# spent mostly on XLA compiling tiny models' programs in one subprocess per stage. Measured 2026-12-02 on 2 cores:
# the whole suite in one run took 688 s of pytest; on a clean clone `make test` took 462 s with its install
# (pytest 442 s) and `make test-e2e` 327 s.
test: $(STAMP)
	JAX_PLATFORMS=cpu $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile -m "not e2e" tests

test-e2e: $(STAMP)
	JAX_PLATFORMS=cpu $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile -m e2e tests

# Rebuild the packaged standard evaluator (corpus -> tokenizer -> tiny T5 -> evaluator -> card); see CARD.md.
standard-assets: $(STAMP)
	PY=$(BIN)/python scripts/build_standard.sh $(STANDARD_WORK)

# Standard evaluator v8 (issue 55), the packaged one: v7's recipe on corpus v5 with hard negatives, and v7's text
# encoder (scripts/build_standard_v8.sh; standard-assets with ENCODER unset trains a new tokenizer and T5).
standard-assets-v8: $(STAMP)
	PY=$(BIN)/python scripts/build_standard_v8.sh $(STANDARD_WORK)-v8

bench: $(STAMP)
	JAX_PLATFORMS=cpu $(BIN)/python benchmarks/synth_annotate.py

clean:
	rm -rf $(VENV) runs build *.egg-info
