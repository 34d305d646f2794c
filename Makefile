# Serra: every target creates and uses .venv by itself.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: run test bench images lint clean venv

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,training]'
	touch $(STAMP)

venv: $(STAMP)

## run: the main end-to-end job on embedded defaults
run: $(STAMP)
	$(PY) -m gateway demo

## test: the whole suite (CI calls this)
test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q

# The peers (mealpy pins numpy < 2) live in their own virtualenv so they never touch .venv.
BENCH_VENV  := .venv-bench
BENCH_STAMP := $(BENCH_VENV)/.installed

$(BENCH_STAMP): pyproject.toml
	$(PYTHON) -m venv $(BENCH_VENV)
	$(BENCH_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(BENCH_VENV)/bin/python -m pip install --quiet -e '.[dev,bench]'
	touch $(BENCH_STAMP)

## bench: speed and memory, side by side with peers; JSON in bench/results/
bench: $(BENCH_STAMP)
	$(BENCH_VENV)/bin/python tests/bench/run.py

## images: MCU firmware bundle and gateway bundle in images/build/
images: $(STAMP)
	$(PY) images/build.py

lint: $(STAMP)
	$(VENV)/bin/ruff check .

clean:
	rm -rf $(VENV) $(BENCH_VENV) images/build bench/results .pytest_cache .ruff_cache
