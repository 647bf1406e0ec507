# Two commands for a fresh machine (Python 3.11 and pip are all they need):
#   make demo   sets up .venv with the package alone and runs the main job
#   make test   sets up .venv with the test extra, then lints, type-checks, builds the API
#               reference and runs the tests (the fast ones first)
# and a few more:
#   make lint   ruff (lint and format) and pyright, as `make test` runs them
#   make docs   the API reference from the docstrings, into docs/api/
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# one worker per core, each test file on one worker (its module fixtures computed once)
# every module of the package (pdoc documents only what a package's __all__ names, so list them all)
MODULES = $(shell find manus -name '*.py' | sed -e 's|/__init__\.py$$||' -e 's|\.py$$||' -e 's|/|.|g' | sort)
PYTEST := $(BIN)/python -m pytest -q -n auto --dist loadfile

.PHONY: demo test lint apicheck docs setup clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# the demo needs the package alone; the test extra is a superset, so it satisfies the demo too.
# manus's bytecode is written at set-up: where Python is told not to write it (PYTHONDONTWRITEBYTECODE,
# as on CI machines), every command would otherwise compile the package again (0.2 s a process)
$(VENV)/.installed-demo: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e .
	$(BIN)/python -m compileall -q manus > /dev/null
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e ".[test]"
	$(BIN)/python -m compileall -q manus > /dev/null
	touch $@ $(VENV)/.installed-demo

setup: $(VENV)/.installed-test

demo: $(VENV)/.installed-demo
	$(BIN)/manus demo

lint: $(VENV)/.installed-test
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/pyright

# the API reference must build (into a scratch directory)
apicheck: $(VENV)/.installed-test
	tmp=$$(mktemp -d) && $(BIN)/pdoc -o $$tmp $(MODULES) && rm -rf $$tmp

docs: $(VENV)/.installed-test
	rm -rf docs/api
	$(BIN)/pdoc -o docs/api $(MODULES)

# pytest's exit 5 (no test selected) is no failure
test: lint apicheck
	$(PYTEST) -m "not slow" || [ $$? -eq 5 ]
	$(PYTEST) -m slow || [ $$? -eq 5 ]

clean:
	rm -rf $(VENV) runs/out docs/api .pytest_cache
