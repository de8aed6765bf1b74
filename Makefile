# Set-up and checks. Everything runs from a virtualenv in .venv that these targets create.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint typecheck pytest bench fuzz clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/cobus demo

test: $(STAMP) lint typecheck pytest

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks examples
	$(BIN)/ruff format --check src tests benchmarks examples

typecheck: $(STAMP)
	$(BIN)/mypy

pytest: $(STAMP)
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py

# Mutation fuzzing of every input (20,000 EDS/DCF + 5,000 YAML + 500 damaged alarm
# histories + 200 mutated or zip-bombed BLF traces), capped at 3 GB of
# address space and 30 minutes; failing inputs land in fuzz-failures/. CI does not run it.
fuzz: $(STAMP)
	ulimit -v 3000000; timeout 1800 $(BIN)/python -m tests.fuzz_inputs --eds 20000 --yaml 5000

clean:
	rm -rf $(VENV) build dist src/*.egg-info .pytest_cache .mypy_cache .ruff_cache
