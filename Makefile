# The two commands of the README: `make run` and `make test`. Both set up
# everything from nothing (venv, install, FMU build).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
FMUS   := build/fmus/manifest.json
OUT    ?= out/ewl

.PHONY: run test fmus bench clean venv

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

# one worker a core, a test file per worker (its module fixtures stay whole): on a fresh
# machine most of the suite is compiling the engine's generated code, one core each
test: $(FMUS)
	$(BIN)/python -m pytest -n auto --dist loadfile

bench: $(FMUS)
	$(BIN)/python bench/run_bench.py

clean:
	rm -rf build out .pytest_cache
