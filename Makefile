# granular_pyg — set-up, demo, tests.  `make demo` and `make test` are the README's two commands.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.installed
TORCH_SPEC ?= torch==2.13.*
LIGGGHTS_INSTALL := apt-get install -y --no-install-recommends liggghts

.PHONY: setup liggghts demo test test-fast lint format bench paper clean

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

# The paper's experiment on this machine: LIGGGHTS datasets, V1/V2/V3 x 3 seeds on the
# hopper and V3 on the drum (one torch thread each, two at a time), evaluation, the variant table.
PAPER := outputs/paper
paper: setup
	$(PY) -m granular_pyg.generate +dem_dataset=paper_hopper jobs=2
	$(PY) -m granular_pyg.generate +dem_dataset=paper_drum jobs=2
	@mkdir -p $(PAPER)
	$(PY) -m granular_pyg.train +experiment=paper_drum model=v3 threads=1 trainer.max_epochs=48 \
		hydra.run.dir=$(PAPER)/train/drum_v3 > $(PAPER)/train_drum_v3.log 2>&1 & \
	for seed in 0 1 2; do for v in v3 v1 v2; do \
		$(PY) -m granular_pyg.train +experiment=paper_hopper model=$$v seed=$$seed threads=1 \
			hydra.run.dir=$(PAPER)/train/$${v}_s$$seed > $(PAPER)/train_$${v}_s$$seed.log 2>&1 & \
		while [ $$(jobs -r | wc -l) -ge 2 ]; do sleep 5; done; done; done; wait
	for run in $(PAPER)/train/*; do \
		$(PY) -m granular_pyg.evaluate ckpt=$$run/checkpoints/last.ckpt 'splits=[train,test]' \
			max_trajectories=5 out=$(PAPER)/evaluate/$$(basename $$run); done
	$(PY) -m granular_pyg.compare "runs=[$$(ls -d $(PAPER)/evaluate/v?_s? | paste -sd,)]" \
		out=$(PAPER)/compare

clean:
	rm -rf $(VENV) outputs multirun .pytest_cache .ruff_cache
