# The two commands of the README: `make demo` and `make test`. Each creates .venv/
# on first use and installs the package with its dependencies into it.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp

.PHONY: setup demo test bench lint clean

$(STAMP): setup.py package.xml setup.cfg
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[ros,test]"
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(PY) -m robot_localization_suite.launch.demo

test: $(STAMP)
	$(PY) -m pytest -q test

bench: $(STAMP)
	$(PY) -m robot_localization_suite.tools.bench --all --out results

lint: $(STAMP)
	$(VENV)/bin/ruff check robot_localization_suite test

clean:
	rm -rf build install log results .pytest_cache
