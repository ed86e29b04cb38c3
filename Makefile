# Quick start: `make demo` (set up + fly the default mission), `make test` (set up + run the tests).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: setup fmu build demo test test-slow lint bench clean

setup: $(STAMP) fmu build

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

fmu: $(STAMP)
	$(PY) -m fmus.build

# the flight software and the master's tick compiled from their Python sources (Cython), and
# the FMI binding; warnings shown (mav/compiled.py: COSIM_COMPILED picks compiled/interpreted)
build: $(STAMP)
	$(PY) -m mav.build
	$(PY) -m cosim.build

demo: setup
	$(VENV)/bin/cosim run scenarios/mambo_seed_track.toml --out runs/demo

test: setup
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -m "not slow"

test-slow: setup
	$(PY) -m pytest -m slow

bench: setup
	$(VENV)/bin/cosim bench

clean:
	rm -rf build runs
