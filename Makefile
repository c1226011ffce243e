# srvol front door. Every target builds its own .venv from pinned requirements.
PY      ?= python3.11
VENV    ?= .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
DEMO    ?= demo_out
THREADS ?= 2

.PHONY: all venv test demo demo-capture bench clean

all: test

$(STAMP): requirements.txt pyproject.toml
	@command -v $(PY) >/dev/null || { echo "make: need $(PY) (Python 3.11: bpy 5.0 supports no other)"; exit 1; }
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -r requirements.txt
	$(BIN)/pip install -q --no-deps -e .
	@touch $(STAMP)

venv: $(STAMP)

test: $(STAMP)
	OMP_NUM_THREADS=$(THREADS) $(BIN)/python -m pytest -q

demo: $(STAMP)
	OMP_NUM_THREADS=$(THREADS) $(BIN)/python -m srvol.demo --out $(DEMO)

demo-capture: $(STAMP)
	OMP_NUM_THREADS=$(THREADS) $(BIN)/python -m srvol.demo --capture --budget 600 --out $(DEMO)_capture

bench: $(STAMP)
	OMP_NUM_THREADS=$(THREADS) $(BIN)/python -m bench.run_all

clean:
	rm -rf $(VENV) $(DEMO) $(DEMO)_capture .pytest_cache
