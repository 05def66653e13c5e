# Two set-up commands for a fresh machine: `make demo` (main job) and `make test` (test suite).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0 || echo "torch 2.13.0 not available: OverlapTransformer tests will skip"
	$(PY) -m pip install --quiet -e ".[dev]"
	$(PY) -m pip install --quiet "rerun-sdk>=0.23" || echo "rerun-sdk not available: the live-viewer tests will skip"
	$(PY) -m pip install --quiet --no-deps map_closures==2.2.0 || echo "map_closures not available: loop_detector=map-closures and its tests will skip"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/msa-slam demo

# -n auto: one pytest worker per core; --dist loadfile keeps each test file (and its module fixtures) on one worker
test: $(STAMP)
	$(PY) -m pytest -q -n auto --dist loadfile

test-slow: $(STAMP)
	$(PY) -m pytest -q -n auto --dist loadfile -m slow

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
