# The README's two set-up commands: `make demo` and `make test`.
# Each creates (or refreshes) .venv and installs the package with its dev extras.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DEMO_DIR ?= runs/demo
STANDARD_WORK ?= runs/standard-build

.PHONY: venv demo test bench standard-assets clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	JAX_PLATFORMS=cpu $(BIN)/python -m handx_jax.demo --out $(DEMO_DIR)

# One pytest worker per core, each test file on one worker (its module fixtures are built once):
# single-process pytest leaves the second core idle most of the run (wall time ~ user CPU time).
TEST_WORKERS ?= auto
test: $(STAMP)
	JAX_PLATFORMS=cpu $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile tests

# Rebuild the packaged standard evaluator (corpus -> tokenizer -> tiny T5 -> evaluator -> card); see CARD.md.
standard-assets: $(STAMP)
	PY=$(BIN)/python scripts/build_standard.sh $(STANDARD_WORK)

bench: $(STAMP)
	JAX_PLATFORMS=cpu $(BIN)/python benchmarks/synth_annotate.py

clean:
	rm -rf $(VENV) runs build *.egg-info
