# Quick start: `make demo` (set up + fly the default mission), `make test` (set up + run the tests).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: setup fmu build demo test test-fast test-slow viewer-setup lint bench docs docs-figures clean

setup: $(STAMP) fmu build

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,docs]'
	touch $(STAMP)

fmu: $(STAMP)
	$(PY) -m fmus.build

# the flight software and the master's tick compiled from their Python sources (Cython), and
# the FMI binding; warnings shown (onesource/switch.py: COSIM_COMPILED picks compiled/interpreted)
build: $(STAMP)
	$(PY) -m onesource.build

demo: setup
	$(VENV)/bin/cosim run scenarios/mambo_seed_track.toml --out runs/demo

# the suite runs in the portable numerics (cosim/numerics.py): its flights are the same bytes
# on every x86-64 CPU, so it passes on any; tests/test_numerics_levels.py flies native too
test: setup
	$(VENV)/bin/ruff check .
	$(PY) -m cosim.numerics portable -- $(PY) -m pytest -m "not slow" -n auto --durations=25
	$(VENV)/bin/cosim test tests/regress/shipped.toml --require-baselines --quiet \
		--out runs/test-shipped --junit runs/test-shipped/junit.xml --report runs/test-shipped/report

# the fast lane for development: unit tests of the parts, no whole flights (tests marked
# `flight` or `slow` are left out; one that flies anyway fails, tests/conftest.py)
test-fast: setup
	$(VENV)/bin/ruff check .
	$(PY) -m pytest --fast --durations=10 -q

# the slow checks include real viewers (tests/viewer): chromium, Playwright, npm packages,
# and Lichtblick's web app built from its sources (the first time: tens of minutes, GBs)
test-slow: setup viewer-setup
	$(PY) -m cosim.numerics portable -- $(PY) -m pytest -m slow

viewer-setup: setup
	bash tests/viewer/setup.sh
	bash tests/viewer/setup_lichtblick.sh

bench: setup
	$(VENV)/bin/cosim bench

# the documentation site (mkdocs.yml, docs/) into build/site; also built by the tests
docs: setup
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict

# the figures of the docs and the README, made from real runs (about a minute)
docs-figures: setup
	$(PY) docs/figures/make_figures.py

clean:
	rm -rf build runs
