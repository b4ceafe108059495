# granular_pyg — set-up, demo, tests.  `make demo` and `make test` are the README's two commands.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.installed
TORCH_SPEC ?= torch==2.13.*
LIGGGHTS_INSTALL := apt-get install -y --no-install-recommends liggghts

.PHONY: setup liggghts demo test test-fast lint format bench clean

setup: $(STAMP) liggghts

# Each step is skipped when its package is already importable, so a second run takes seconds.
$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(PY) -c "import torch" 2>/dev/null || $(PIP) install "$(TORCH_SPEC)"
	@$(PY) -c "import setuptools, wheel" 2>/dev/null || $(PIP) install setuptools wheel
	@$(PY) -c "import torch_cluster" 2>/dev/null || { \
		echo ">> building torch-cluster from source (about 12 min on 2 cores; pip caches the wheel)"; \
		$(PIP) install --no-build-isolation torch-cluster; }
	$(PIP) install -e ".[dev]"
	@touch $(STAMP)

liggghts:
	@if command -v liggghts >/dev/null 2>&1; then \
		echo ">> LIGGGHTS: $$(command -v liggghts)"; \
	elif [ "$$(id -u)" = "0" ]; then \
		echo ">> installing LIGGGHTS (Debian package)"; \
		$(LIGGGHTS_INSTALL) || { apt-get update && $(LIGGGHTS_INSTALL); }; \
	else \
		echo ">> LIGGGHTS is missing; as root run:  $(LIGGGHTS_INSTALL)"; \
	fi

demo: setup
	$(PY) -m granular_pyg.demo

test: setup
	$(PY) -m pytest

test-fast: setup
	$(PY) -m pytest -m "not slow"

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: setup
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

bench: setup
	$(PY) -m granular_pyg.bench suite=geometry

clean:
	rm -rf $(VENV) outputs multirun .pytest_cache .ruff_cache
