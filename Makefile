# The two commands of the README: `make demo` and `make test`. Each creates .venv/
# on first use (only Python >= 3.10 with pip is needed), installs the package with its
# dependencies and the ROS 2 Jazzy wheels into it, then runs.
#   make demo DEMO_ARGS="--speed 2"       options of rls_demo (see .venv/bin/rls_demo --help)
#   make test PYTEST_ARGS="-k raycast"    options of pytest
#   make bench BENCH_ARGS="--skip ial_localizer:fr101"   options of rls_bench (see .venv/bin/rls_bench --help)
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
DEMO_ARGS ?=
PYTEST_ARGS ?=
BENCH_MAX_SECONDS ?= 300
BENCH_ARGS ?=

.PHONY: setup demo test bench lint clean

# Reinstalled whenever the package metadata changes.
$(STAMP): setup.py setup.cfg package.xml pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[ros,test]"
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(PY) -m robot_localization_suite.launch.demo $(DEMO_ARGS)
	$(PY) -m robot_localization_suite.launch.demo --scenario lab_camera --localizers ima_topo_localizer $(DEMO_ARGS)

test: $(STAMP)
	$(PY) -m pytest -q test $(PYTEST_ARGS)

# Every localizer over every bag in bags/, in global then tracking mode, plus single-scan
# global fixes; each run stops after BENCH_MAX_SECONDS of wall time (reported as truncated).
bench: $(STAMP)
	$(PY) -m robot_localization_suite.tools.bench --all --with-tracking --with-global-fixes --out results \
		--max-seconds $(BENCH_MAX_SECONDS) $(BENCH_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check robot_localization_suite test
	$(VENV)/bin/mypy

clean:
	rm -rf build install log results .pytest_cache
