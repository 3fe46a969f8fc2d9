# Fresh-machine entry points: `make serve` (API + embedded Redis + one worker) and `make test`.
# The venv is created on first use; torch is the CPU build 2.13.0 (never a CUDA build).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
export OMP_WAIT_POLICY ?= PASSIVE

.PHONY: install serve test lint bench-render docs-bench
install: $(VENV)/.installed

# One line per step. pip's own output (this machine's pip configuration warns a lot) goes to the log, whose
# tail is shown if a step fails. The pip commands and pip's configuration are otherwise untouched: that
# configuration is what finds the CPU torch build (bypassing it, e.g. --isolated, pulls a CUDA build).
INSTALL_LOG := $(VENV)/install.log
define install_step
	@echo "make install: $(1)"
	@$(2) >>$(INSTALL_LOG) 2>&1 || { tail -n 30 $(INSTALL_LOG); echo "make install: $(1) failed; full log: $(INSTALL_LOG)"; exit 1; }
endef

$(VENV)/.installed: pyproject.toml
	@echo "make install: creating $(VENV) (pip's output goes to $(INSTALL_LOG))"
	@$(PY) -m venv $(VENV)
	$(call install_step,upgrading pip,$(BIN)/pip install --upgrade pip)
	$(call install_step,installing torch 2.13.0 (CPU build),$(BIN)/pip install torch==2.13.0)
	$(call install_step,installing ctp and its dependencies,$(BIN)/pip install -e ".[dev]")
	@touch $@
	@echo "make install: done ($(VENV))"

serve: install
	$(BIN)/ctp serve

test: install
	$(BIN)/pytest -q -rs

lint: install
	$(BIN)/ruff check .

# The result tables of docs/benchmarks.md, regenerated from the stored runs under benchmarks/results/
# (each: results.jsonl and commands.txt as `ctp bench` writes them, run.json with the machine kind and date).
docs-bench: install
	$(BIN)/python benchmarks/docs_tables.py
