# The two commands of the README: `make demo` and `make test`. Each creates .venv/
# on first use (only Python >= 3.10 with pip is needed), installs the package with its
# dependencies and the ROS 2 Jazzy wheels into it, then runs.
#   make demo DEMO_ARGS="--speed 2"       options of rls_demo (see .venv/bin/rls_demo --help)
#   make test PYTEST_ARGS="-k raycast"    options of pytest
#   make bench BENCH_ARGS="--skip ial_localizer:fr101"   options of rls_bench (see .venv/bin/rls_bench --help)
#   make bench-cv                         only the cross-validation runs (honest maps) on the real logs
#   make bench-campus                     the Freiburg campus (its bag is made on demand): IR and PIL fixes,
#                                         the trackers replayed
#   make bench-paper                      PIL, IR, IAL and IMA as their papers describe them (config/*_paper.yaml)
#   make bench BENCH_WORKERS=2            runs side by side (Dask workers): faster, but the update times then
#                                         share the cores and differ from the published tables (1: one at a time)
#   make soak SOAK_ARGS="--speed 10"      options of rls_soak (see .venv/bin/rls_soak --help)
#   make footprint FOOTPRINT_ARGS="--no-cold"   options of rls_footprint (see .venv/bin/rls_footprint --help)
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
# tf2_msgs and nav2_msgs built from interfaces/ into the venv (no wheels on PyPI; interfaces/README.md).
INTERFACES := $(VENV)/.interfaces-stamp
INTERFACE_FILES := $(shell find interfaces -type f)
DEMO_ARGS ?=
PYTEST_ARGS ?=
BENCH_MAX_SECONDS ?= 300
BENCH_ARGS ?=
BENCH_WORKERS ?= 1
SOAK_MINUTES ?= 30
SOAK_ARGS ?=
FOOTPRINT_ARGS ?=
# Real logs for the cross-validation runs; their 5-block splits are made once, when missing.
CARMEN_DIR ?= ../shared/data/carmen
CV_SPLITS ?= results/cv_splits
CV_LOGS := intel fr101 orebro
CV_LOG_FILE_intel := intel-corrected.log.gz
CV_LOG_FILE_fr101 := freiburg-101-corrected.log.gz
CV_LOG_FILE_orebro := orebro-corrected.log.gz
CV_INDEXES := $(foreach log,$(CV_LOGS),$(CV_SPLITS)/$(log)_cv.yaml)
HAVE_CARMEN := $(wildcard $(CARMEN_DIR))

.PHONY: setup demo test bench bench-cv bench-campus bench-paper soak footprint lint clean

# Reinstalled whenever the package metadata changes.
$(STAMP): setup.py setup.cfg package.xml pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[ros,test,interfaces,viz,scale]"
	touch $(STAMP)

# Once (again when interfaces/ or the install changes): colcon with the ament_cmake/rosidl wheels,
# installed into the venv itself, whose lib/ the rclpy wheels already put on the library path.
$(INTERFACES): $(STAMP) $(INTERFACE_FILES)
	AMENT_PREFIX_PATH=$(CURDIR)/$(VENV) CMAKE_PREFIX_PATH=$(CURDIR)/$(VENV) $(PY) -m colcon \
		--log-base $(VENV)/interfaces/log build --base-paths interfaces/tf2_msgs interfaces/nav2_msgs \
		--build-base $(VENV)/interfaces/build --install-base $(VENV) --merge-install \
		--event-handlers console_direct- \
		--cmake-args -DCMAKE_PROJECT_INCLUDE=$(CURDIR)/interfaces/wheel_includes.cmake -DBUILD_TESTING=OFF
	touch $(INTERFACES)

setup: $(STAMP) $(INTERFACES)

demo: $(STAMP) $(INTERFACES)
	$(PY) -m robot_localization_suite.launch.demo $(DEMO_ARGS)
	$(PY) -m robot_localization_suite.launch.demo --scenario lab_camera --localizers ima_topo_localizer $(DEMO_ARGS)

test: $(STAMP) $(INTERFACES)
	$(PY) -m pytest -q test $(PYTEST_ARGS)

# Every localizer over every bag in bags/, in global then tracking mode, plus single-scan
# global fixes; each run stops after BENCH_MAX_SECONDS of wall time (reported as truncated).
# With the real logs at hand, then the same over the 5-block splits of intel, fr101 and orebro
# (each block on its honest map and on the whole-log map) into results/cv/, its tables
# appended to results/summary.md.
bench: $(STAMP) $(INTERFACES) $(if $(HAVE_CARMEN),$(CV_INDEXES))
	@$(if $(HAVE_CARMEN),true,echo "bench: $(CARMEN_DIR) is absent: skipping the cross-validation runs (honest maps)")
	$(PY) -m robot_localization_suite.tools.bench --all --with-tracking --with-global-fixes --out results \
		--max-seconds $(BENCH_MAX_SECONDS) --workers $(BENCH_WORKERS) $(if $(HAVE_CARMEN),--cv $(CV_INDEXES)) \
		$(BENCH_ARGS)

# The methods with a paper profile, as published, on every bag: results/paper/summary.md, and after a make bench
# results/paper/comparison.md (each method's paper and ours rows, bag by bag).
bench-paper: $(STAMP) $(INTERFACES)
	$(PY) -m robot_localization_suite.tools.bench --all \
		--localizers pil_localizer ir_initializer ial_localizer ima_topo_localizer --profile paper \
		--out results/paper --max-seconds $(BENCH_MAX_SECONDS) --workers $(BENCH_WORKERS) \
		$(if $(wildcard results/summary.json),--compare-with ours=results) $(BENCH_ARGS)

# Only the cross-validation runs: results/cv/summary.md.
ifeq ($(HAVE_CARMEN),)
bench-cv:
	$(error bench-cv: $(CARMEN_DIR) is absent, no real logs to cut into blocks)
else
bench-cv: $(STAMP) $(CV_INDEXES)
	$(PY) -m robot_localization_suite.tools.bench --cv $(CV_INDEXES) --with-tracking --with-global-fixes \
		--out results --max-seconds $(BENCH_MAX_SECONDS) $(BENCH_ARGS)
endif

# A log's split (bags, maps, index); remade only when its index is missing (delete it to remake).
$(CV_SPLITS)/%_cv.yaml: | $(STAMP)
	$(PY) -m robot_localization_suite.tools.carmen_to_bag $(CARMEN_DIR)/$(CV_LOG_FILE_$*) $(CV_SPLITS) \
		--blocks 5 --name $* --overwrite

# The Freiburg campus (5,166 x 5,492 cells at 5 cm): its bag is larger than bags/' 30 MB budget, so it
# is made here on demand, once; single-scan global fixes of the methods with a precomputed index, then
# the trackers replayed from the first true pose (results/campus_bench/tracking/: peak RSS of every node).
CAMPUS_BAG ?= results/campus
ifeq ($(HAVE_CARMEN),)
bench-campus:
	$(error bench-campus: $(CARMEN_DIR) is absent, no campus log to convert)
else
bench-campus: $(STAMP) $(INTERFACES) $(CAMPUS_BAG)/metadata.yaml
	$(PY) -m robot_localization_suite.tools.bench $(CAMPUS_BAG) --localizers ir_initializer pil_localizer \
		--global-fixes --every 20 --out results/campus_bench --max-seconds $(BENCH_MAX_SECONDS) $(BENCH_ARGS)
	$(PY) -m robot_localization_suite.tools.bench $(CAMPUS_BAG) --localizers mcl_baseline hybrid_localizer \
		ial_localizer --mode tracking --out results/campus_bench/tracking --max-seconds $(BENCH_MAX_SECONDS) \
		$(BENCH_ARGS)
endif

$(CAMPUS_BAG)/metadata.yaml: | $(STAMP)
	$(PY) -m robot_localization_suite.tools.carmen_to_bag $(CARMEN_DIR)/freiburg-campus-corrected.log.gz \
		$(CAMPUS_BAG) --overwrite

# Load and soak (docs/soak.md): scan_sim at 4x with every localizer for SOAK_MINUTES, each process's
# RSS and CPU every 10 s, pose latency and dropped scans, into results/soak/ (soak.md, soak.json, soak.png).
soak: $(STAMP) $(INTERFACES)
	$(PY) -m robot_localization_suite.tools.soak --minutes $(SOAK_MINUTES) --out results/soak $(SOAK_ARGS)

# Memory, CPU and start-up of each localizer alone and of all composed (docs/footprint.md): idle RSS after
# configure, RSS and CPU replaying bags/office_kidnap at real time, start-up with a cold and a warm cache,
# into results/footprint/ (footprint.md, footprint.json). A measurement, not a test.
footprint: $(STAMP) $(INTERFACES)
	$(PY) -m robot_localization_suite.tools.footprint --out results/footprint $(FOOTPRINT_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check robot_localization_suite test
	$(VENV)/bin/mypy

clean:
	rm -rf build install log results .pytest_cache
