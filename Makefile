# Fresh-machine entry points: `make serve` (API + embedded Redis + one worker) and `make test`.
# The venv is created on first use; torch is the CPU build 2.13.0 (never a CUDA build).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
export OMP_WAIT_POLICY ?= PASSIVE

.PHONY: install serve test lint bench-render
install: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e ".[dev]"
	touch $@

serve: install
	$(BIN)/ctp serve

test: install
	$(BIN)/pytest -q -rs

lint: install
	$(BIN)/ruff check .
