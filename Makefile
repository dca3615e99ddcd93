# Quick start:   make run    (set up .venv, run the main job on embedded defaults)
#                make test   (set up .venv, run the test suite)
# Both need only Python >= 3.11 and make; everything else is installed into .venv.

PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3 2>/dev/null)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run walk test test-all bench lint venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	@test -n "$(PYTHON)" || { echo "error: no python3.11/python3 on PATH"; exit 1; }
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' || \
	  { echo "error: jaxloco needs Python >= 3.11, found $$($(PYTHON) --version)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@# setuptools says an editable install of a package mapped from several folders is
	@# "information only" (a UserWarning); nothing in it needs acting on.
	PYTHONWARNINGS=ignore::UserWarning $(BIN)/python -m pip install --quiet -c constraints.txt -e ".[dev]"
	@touch $(STAMP)

# The main job on embedded defaults: the limit search (the largest recovered impulse for
# 8 directions x 5 gait phases, replanning on and off; about 6 min on 2 cores from a fresh
# clone, .venv and compile cache included). Outputs and the report land in hydra's run
# directory under outputs/; running it again there resumes.
run: $(STAMP)
	$(BIN)/jaxloco push-sweep

# The steering walk with a push: Fig. 11's schedule on the full robot, pushed from the side
# at the start of its straight segment; plots and a video (about 5 minutes).
walk: $(STAMP)
	$(BIN)/jaxloco walk-steer \
	  'pushes=[{magnitude:250,direction_deg:90,start:11.5,duration:0.1}]'

# The CI suite: everything except full-size end-to-end runs (their small versions run here).
# Two workers, one test file each at a time (tests of a file share compiled functions): XLA
# compiles on one thread, so two at once use both cores (measured: 22:26 -> 16:21 on 2 cores).
# Files start longest first (tests/conftest.py), not xdist's most-tests-first.
TEST_WORKERS ?= 2
test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder --durations=15

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder --runslow

bench: $(STAMP)
	-PYTHONWARNINGS=ignore::UserWarning $(BIN)/python -m pip install --quiet -c constraints.txt -e ".[bench]"
	for b in planner learning dynamics wblc closed_loop sweep tuning; do \
	  $(BIN)/python benchmarks/bench_$$b.py --json benchmarks/results/bench_$$b.json || exit 1; done
	$(BIN)/python benchmarks/render_results.py

lint: $(STAMP)
	$(BIN)/ruff check jaxloco experiments tests benchmarks

clean:
	rm -rf $(VENV) outputs multirun .pytest_cache
