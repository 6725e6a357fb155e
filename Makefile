# The two commands of the README: `make run` and `make test`. Both set up
# everything from nothing (venv, install, FMU build).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
FMUS   := build/fmus/manifest.json
OUT    ?= out/ewl

.PHONY: run test test-all fmus bench clean venv

$(STAMP): pyproject.toml
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

$(FMUS): $(STAMP) $(wildcard fmus/*.py webline/*.py webline/physics/*.py)
	$(BIN)/webline build-fmus

fmus: $(FMUS)

run: $(FMUS)
	$(BIN)/webline run scenarios/ewl_out_of_round.yaml --out $(OUT) --csv
	$(BIN)/webline plot $(OUT)

# One worker a core, a test file per worker (its module fixtures stay whole). `make test`
# (CI's command) leaves out the tests marked slow: whole blind diagnoses that on a fresh
# machine, every engine structure compiled anew, hold the suite past CI's 90 minutes;
# `make test-all` runs them too. Files go out in conftest's order (the long diagnoses
# first), not xdist's default of the files with most tests first.
PYTEST := $(BIN)/python -m pytest -n auto --dist loadfile --no-loadscope-reorder

test: $(FMUS)
	$(PYTEST) -m "not slow"

test-all: $(FMUS)
	$(PYTEST)

bench: $(FMUS)
	$(BIN)/python bench/run_bench.py

clean:
	rm -rf build out .pytest_cache
