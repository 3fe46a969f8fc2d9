# Fresh-machine entry points: `make serve` (API + embedded Redis + one worker) and `make test`.
# The venv is created on first use; torch is the CPU build 2.13.0 (never a CUDA build).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
export OMP_WAIT_POLICY ?= PASSIVE

.PHONY: install serve test lint typecheck bench-render docs-bench
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

# Ctrl-C ends `ctp serve` with status 130: a normal stop here, not a make error
serve: install
	@$(BIN)/ctp serve || [ $$? -eq 130 ]

# Two test processes (pytest-xdist), each test file whole on one of them (its module-scoped API and worker started
# once), each process with its own private Redis: the suite's own processes leave a 2-core machine about half idle
# when run one at a time. TEST_WORKERS=0 runs it in one process.
TEST_WORKERS ?= 2
test: install
	$(BIN)/pytest -q -rs $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile)

# .ci/run runs both before the tests. ruff's rules: [tool.ruff] in pyproject.toml.
lint: install
	$(BIN)/ruff check .

# mypy on ctp_core, service, worker and ctp ([tool.mypy]'s files), at the level set there, with the modules still
# to be raised listed there
typecheck: install
	$(BIN)/mypy

# The result tables of docs/benchmarks.md, regenerated from the stored runs under benchmarks/results/
# (each: results.jsonl and commands.txt as `ctp bench` writes them, run.json with the machine kind and date).
docs-bench: install
	$(BIN)/python benchmarks/docs_tables.py

# The Blender add-on (integrations/blender, a Blender extension) as the zip a user installs from disk
# (docs/blender.md); named as Blender names extension packages, <id>-<version>.zip.
BLENDER_ADDON_SRC := integrations/blender/blender_manifest.toml $(wildcard integrations/blender/*.py)
BLENDER_ADDON := dist/ctp_place-$(shell sed -n 's/^version = "\(.*\)"/\1/p' integrations/blender/blender_manifest.toml).zip
.PHONY: blender-addon test-blender docs-blender
blender-addon: $(BLENDER_ADDON)
$(BLENDER_ADDON): $(BLENDER_ADDON_SRC)
	@mkdir -p dist
	@rm -f $@
	cd integrations/blender && $(PY) -m zipfile -c $(CURDIR)/$@ $(notdir $(BLENDER_ADDON_SRC))

# The add-on's tests (tests/blender) in real headless Blender: the bpy module (CPython 3.11) in a venv of its own,
# as it pins numpy<2, which the project's venv cannot have. They start `ctp serve` from the project's venv.
BLENDER_VENV := .venv-blender
$(BLENDER_VENV)/.installed: tests/blender/requirements.txt
	@echo "make test-blender: creating $(BLENDER_VENV) (pip's output goes to $(BLENDER_VENV)/install.log)"
	@$(PY) -m venv $(BLENDER_VENV)
	@$(BLENDER_VENV)/bin/pip install -r tests/blender/requirements.txt >$(BLENDER_VENV)/install.log 2>&1 || \
	  { tail -n 30 $(BLENDER_VENV)/install.log; echo "make test-blender: install failed"; exit 1; }
	@touch $@

# --confcutdir: the project's tests/conftest.py imports ctp, which is not in this venv
test-blender: install $(BLENDER_VENV)/.installed
	CTP_BIN=$(CURDIR)/$(BIN)/ctp $(BLENDER_VENV)/bin/pytest -q -rs --confcutdir=tests/blender tests/blender

# docs/blender.md's picture, rendered by the Blender tests
docs-blender: install $(BLENDER_VENV)/.installed
	CTP_BLENDER_PICTURE=$(CURDIR)/docs/blender-result.png CTP_BIN=$(CURDIR)/$(BIN)/ctp \
	  $(BLENDER_VENV)/bin/pytest -q -rs --confcutdir=tests/blender tests/blender -k places_the_cup
