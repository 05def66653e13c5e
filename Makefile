# Two set-up commands for a fresh machine: `make demo` (main job) and `make test` (test suite). Each installs only
# what it runs: the demo the package; the tests also pytest, pytest-xdist and the optional extras their tests
# exercise (`make extras`: torch for the OverlapTransformer, CPU build, rerun-sdk for the live viewer and map_closures
# for loop_detector=map-closures, without its numpy pin, which it works without;
# without them those tests skip).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
BASE := $(VENV)/.installed-base
DEV := $(VENV)/.installed-dev
EXTRAS := $(VENV)/.installed-extras

.PHONY: demo test test-slow lint bench extras clean

$(BASE): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $(BASE)

$(DEV): $(BASE)
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(DEV)

$(EXTRAS): $(BASE)
	$(PY) -m pip install --quiet torch==2.13.0 || echo "torch 2.13.0 not available: OverlapTransformer tests will skip"
	$(PY) -m pip install --quiet "rerun-sdk>=0.23" || echo "rerun-sdk not available: the live-viewer tests will skip"
	$(PY) -m pip install --quiet --no-deps map_closures==2.2.0 || echo "map_closures not available: loop_detector=map-closures and its tests will skip"
	touch $(EXTRAS)

demo: $(BASE)
	$(VENV)/bin/msa-slam demo

# -n auto: one pytest worker per core; --dist loadfile keeps each test file (and its module fixtures) on one worker;
# --no-loadscope-reorder hands the files out in the order tests/conftest.py gives them (the heaviest first);
# --durations=10 prints the ten slowest tests of every run (docs/performance.md keeps them)
test: $(DEV) $(EXTRAS)
	$(PY) -m pytest -q -n auto --dist loadfile --no-loadscope-reorder --durations=10

# The tests marked slow (end-to-end runs whose code paths the default suite also covers more cheaply); CI runs three of them
test-slow: $(DEV) $(EXTRAS)
	$(PY) -m pytest -q -n auto --dist loadfile --no-loadscope-reorder -m slow

# Type-checks the packages [tool.mypy] lists in pyproject.toml; no prerequisite: run it after `make test` (whose
# dev install brings mypy), so it never installs anything itself
lint:
	$(PY) -m ruff check src tests benchmarks
	$(PY) -m ruff format --check src tests benchmarks
	$(PY) -m mypy

bench: $(BASE)
	for b in benchmarks/bench_*.py; do $(PY) $$b || exit 1; done

extras: $(EXTRAS)

clean:
	rm -rf $(VENV) build *.egg-info
