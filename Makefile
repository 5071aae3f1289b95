# damper-hil: `make demo` and `make test` build .venv/ from nothing and run.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
DEPS := $(VENV)/.dependencies
STAMP := $(VENV)/.installed

.PHONY: demo test lint test-collect test-cores test-nodes fuzz bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet uv

# uv resolves and installs the same versions as pip, in a fraction of the time (the
# dependencies' wheels, ROS 2's included, are most of a fresh `make test`); pip if uv fails.
# --compile-bytecode as pip does, and compileall for the packages here: where
# PYTHONDONTWRITEBYTECODE is set, every process would otherwise compile each module it
# imports again (a CLI start 1.1 -> 2.8 s)
$(DEPS): $(BIN)/python pyproject.toml
	$(BIN)/python -m uv pip install --quiet --compile-bytecode --python $(BIN)/python -e '.[test]' \
	    || $(BIN)/python -m pip install --quiet -e '.[test]'
	$(BIN)/python -m compileall -q damper_emulator ride_sim can_bridge damper_hil
	touch $(DEPS)

# the install's second half: the kernels a first run needs compiled into numba's cache
# (damper_hil.warm, on one core), so a newcomer's first demo loads them
$(STAMP): $(DEPS)
	$(BIN)/python -m damper_hil.warm
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/damper-hil demo --out demo_out

# the tests in three parts: the cores (one process per core, pytest-xdist, each module on
# one worker, its fixtures built once; the modules with slow tests first,
# tests/conftest.py, not xdist's order by the number of tests) and, at the same time, the
# ROS and CAN tests (each file on one of two workers, --dist loadfile: a file's ROS
# domains, buses and shared runs stay on one worker); the ROS and CAN tests leave part of
# the CPU idle while their runs wait on the wall clock, and the nodes' loops run under
# SCHED_FIFO and ride through the cores' load; each part's output printed whole when it
# ends (--output-sync); then the wall-clock checks that need the machine to themselves
# (timing), alone.  Each test process takes one BLAS thread: four of them share two cores,
# and OpenBLAS's threads spin before they sleep (with a thread per core the cores stage
# took a tenth more CPU time)
# pytest rewrites each test module's asserts when it imports it, and where
# PYTHONDONTWRITEBYTECODE is set it does so again in every process that collects (a third
# of a collection, five of them): the tests let it keep that in tests/__pycache__, and one
# collection fills it before the workers start, beside the type check and the install's
# warm-up (which needs one core)
PYTEST := PYTHONDONTWRITEBYTECODE= OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -q --durations=10

test: $(DEPS)
	$(MAKE) --no-print-directory -j3 --output-sync=target $(STAMP) lint test-collect
	$(MAKE) --no-print-directory -j2 --output-sync=target test-cores test-nodes
	$(PYTEST) -m timing

lint: $(DEPS)
	$(BIN)/ruff check .
	$(BIN)/mypy

test-collect: $(DEPS)
	@$(PYTEST) --collect-only -qq > $(VENV)/collect.log || { cat $(VENV)/collect.log; exit 1; }

test-cores: $(STAMP)
	$(PYTEST) -n 2 --dist loadscope --no-loadscope-reorder -m "not ros and not can and not timing"

test-nodes: $(STAMP)
	$(PYTEST) -n 2 --dist loadfile -m "(ros or can) and not timing"

fuzz: $(STAMP)
	HYPOTHESIS_PROFILE=fuzz $(BIN)/python -m pytest -q --durations=15 tests/test_fuzz_*.py

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py --doc docs/performance.md

clean:
	rm -rf $(VENV) demo_out .pytest_cache .hypothesis .mypy_cache
