# Two entry points, both doing all the set-up on a fresh machine:
#   make demo   - installs geofeat in .venv and runs the demo on the shipped Kinect frame
#   make test   - installs geofeat with its test extras in .venv and runs the test suite
# and the documentation site:
#   make docs   - installs the docs extra in .venv and builds the site into site/ (strict)
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.geofeat-installed
DOCS_STAMP := $(VENV)/.geofeat-docs-installed

.PHONY: demo test docs bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[test]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/geofeat demo --out out/demo

test: $(STAMP)
	$(PY) -m pytest -n 2 --durations=10

$(DOCS_STAMP): $(STAMP)
	$(PY) -m pip install -q -e ".[docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict

bench: $(STAMP)
	for f in benchmarks/bench_*.py; do $(PY) $$f || exit 1; done

clean:
	rm -rf $(VENV) out site .pytest_cache
