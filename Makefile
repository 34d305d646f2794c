# Serra: every target creates and uses .venv by itself.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: run demo test bench bench-generality bench-forecasts images lint typecheck clean venv stubs

# The wheel carries gateway/ only (pyproject.toml); training/ and the other repository tools
# are importable in the dev venvs, from any folder and in subprocesses, through this .pth.
CHECKOUT_PTH = -c 'import os, sysconfig; open(os.path.join(sysconfig.get_path("purelib"), \
	"serra-checkout.pth"), "w").write(os.getcwd() + "\n")'

$(STAMP): pyproject.toml
	@echo "make: creating $(VENV) (once, and again when pyproject.toml changes): the gateway," \
	      "training, test and cloud packages (~700 MB installed); pip works quietly:" \
	      "~30 s from cached wheels, minutes when it downloads them"
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,training,cloud]'
	$(PY) $(CHECKOUT_PTH)
	touch $(STAMP)

venv: $(STAMP)

# --- MicroPython ESP32 stubs: mcu/ is type-checked against them (tests/test_firmware.py). ---
# Installed apart from the venv (pip --target, gitignored): they shadow CPython's typeshed.
STUBS := mcu/typings_esp32/.installed
$(STUBS): $(STAMP)
	$(PY) -m pip install --quiet --upgrade --target mcu/typings_esp32 \
		'micropython-esp32-stubs==1.29.0.post1'
	touch $(STUBS)

stubs: $(STUBS)

## run: the whole kit live on this machine: key, gateway, simulated kit (real firmware under
## MicroPython), subscriber, status screen; q or Ctrl-C stops it all (python -m training run)
run: $(STAMP)
	$(PY) -m training run

## demo: the offline loop on shipped data: simulate → calibrate → replay → diagnose (out/demo/)
demo: $(STAMP)
	$(PY) -m training demo

## test: the whole suite (CI calls this), in two worker processes (pytest-xdist; CI has 2 cores):
## a test file stays in one worker, so its module fixtures are built once
test: $(STAMP) $(STUBS)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q -n 2 --dist loadfile

# The peers (mealpy pins numpy < 2) live in their own virtualenv so they never touch .venv.
BENCH_VENV  := .venv-bench
BENCH_STAMP := $(BENCH_VENV)/.installed

$(BENCH_STAMP): pyproject.toml
	$(PYTHON) -m venv $(BENCH_VENV)
	$(BENCH_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(BENCH_VENV)/bin/python -m pip install --quiet -e '.[dev,bench,training,cloud]'
	$(BENCH_VENV)/bin/python $(CHECKOUT_PTH)
	touch $(BENCH_STAMP)

## bench: speed and memory, side by side with peers (the fleet bench needs the cloud extra and PostgreSQL's server binaries); JSON in bench/results/
bench: $(BENCH_STAMP)
	$(BENCH_VENV)/bin/python tests/bench/run.py

## bench-generality: diagnosis and forecasts on three independent generators (one held out),
## 3 weather windows, every change kind, 10 effect-free windows each; parallel processes.
## JSON in bench/results/generality.json, Markdown into docs/effects.md ("Generality suite").
bench-generality: $(STAMP)
	$(PY) tests/generality/suite.py --jobs 2

## bench-forecasts: the suite's forecast part alone (9 effect-free replays; persistence, ARX, adaptive,
## adaptive + disturbance filter, combined, corrected; measured weather and outlook). JSON in bench/results/forecasts.json.
bench-forecasts: $(STAMP)
	$(PY) tests/generality/forecasts.py --jobs 2

## images: MCU firmware bundle and gateway bundle in images/build/
images: $(STAMP)
	$(PY) images/build.py

lint: $(STAMP)
	$(VENV)/bin/ruff check .

## typecheck: mypy on gateway/ ([tool.mypy] in pyproject.toml); apart from `make test`, whose time
## it would add to (mcu/ is type-checked against the ESP32 stubs inside the suite)
typecheck: $(STAMP)
	$(PY) -m mypy gateway

clean:
	rm -rf $(VENV) $(BENCH_VENV) mcu/typings_esp32 images/build bench/results .pytest_cache .ruff_cache
