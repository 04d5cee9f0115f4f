# Two commands on a fresh machine: `make run` and `make test`.
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip -q --disable-pip-version-check
STAMP := $(VENV)/.installed
PORT ?= 8866
# Quick mode for heavy notebook/test steps is for `make test` only (`make run` gives users the
# paper's settings); `PYFREP_QUICK=0 make test` runs the tests with the paper's settings.
test: export PYFREP_QUICK ?= 1

.PHONY: setup run test lint browser bench clean

$(STAMP): pyproject.toml constraints.txt
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PIP) install --upgrade pip
	$(PIP) install -c constraints.txt torch==2.13.0
	$(PIP) install -c constraints.txt -e ".[dev]"
	@# the meshers' compiled loops, once (numba caches them): else the first mesh after an install waits ~12 s
	@# (a lattice's mesh runs the fold search's loops too)
	$(PY) -c "from pyfrep_core import polygonize; from pyfrep_core.models import fig1_part, microstructure; \
		[polygonize(fig1_part, ((-1.1,) * 3, (1.1,) * 3), 32, method=m, progress=False) for m in ('mc', 'dc')]; \
		polygonize(microstructure, microstructure.bounds, 24, method='dc', progress=False)"
	@touch $(STAMP)

setup: $(STAMP)

# Debian's chromium for the real-browser tests (Playwright cannot download its own here).
browser:
	@command -v chromium >/dev/null 2>&1 || { \
		echo "installing chromium (apt)"; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium fonts-liberation >/dev/null; }

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test: setup browser lint
	$(VENV)/bin/pytest -q tests pyfrep_core workbench
	@if ls notebooks/*.ipynb >/dev/null 2>&1; then \
		$(VENV)/bin/pytest -q -o addopts=-ra --nbval-lax --nbval-current-env notebooks/; fi

# The workbench in a browser: Voila serves notebooks/workbench.ipynb; idle kernels are culled.
# Template "pyfrep" (workbench/jupyter): Voila's lab page without its CDN stylesheets (offline).
# A pre-heated kernel has run the notebook (imports, first mesh, the model's compiled kernels)
# before the page is asked for; the next one is started a minute later, not while the page is new.
run: setup
	@echo "workbench: http://localhost:$(PORT)/"
	JUPYTER_PATH=$(CURDIR)/workbench/jupyter $(VENV)/bin/voila notebooks/workbench.ipynb --no-browser \
		--port=$(PORT) --template=pyfrep \
		--MappingKernelManager.cull_idle_timeout=120 --MappingKernelManager.cull_interval=30 \
		--preheat_kernel=True --VoilaConfiguration.default_pool_size=1 --VoilaKernelManager.fill_delay=60

bench: setup
	for b in benchmarks/*.py; do $(PY) $$b; done

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
