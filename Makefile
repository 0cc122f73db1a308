# Set-up and main commands. `make demo` and `make test` work on a fresh clone with only Python 3.10+.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
TORCH_VERSION ?= 2.13.0
# torch's CPU build, for machines without an NVIDIA GPU: Linux wheels carry it as the local version `+cpu`;
# PyPI's wheels for macOS and Windows are CPU builds under the plain version.
TORCH_CPU := torch==$(TORCH_VERSION)$(if $(filter Linux,$(shell uname -s)),+cpu,)
# An index with torch's CPU builds, tried last and only as an *extra* index (pip's own index, find-links and
# mirror settings stay in force for everything else). Set it to your mirror of it, or empty to never ask it.
TORCH_CPU_INDEX ?= https://download.pytorch.org/whl/cpu
STAMP := $(VENV)/.samp-installed

.PHONY: install lock demo test test-fast bench docs docs-serve clean-cache

install: $(STAMP)

# torch is installed first and only when missing, through pip as it is configured (pip.conf, PIP_INDEX_URL,
# PIP_EXTRA_INDEX_URL, PIP_FIND_LINKS: a mirror works as it does for every other package). With an NVIDIA
# GPU: torch==$(TORCH_VERSION) from there. Without one, only the CPU build, never a CUDA one: a local wheel
# in pip's find-links (its dependencies come with the package install below), else pip's indexes, else
# TORCH_CPU_INDEX as an extra index; if none has it, the install stops and says what to set.
# constraints.txt pins every package to the version the test suite passed with: a dataset's bytes (and so its
# content id) depend on the numeric libraries, so the same clone must install the same versions. `make lock`
# rewrites it from the current environment after an upgrade has passed `make test`.
$(STAMP): pyproject.toml constraints.txt
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@if ! $(PY) -c "import torch" >/dev/null 2>&1; then \
	  if command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then \
	    echo "NVIDIA GPU found: installing torch==$(TORCH_VERSION) with CUDA"; \
	    $(PY) -m pip install "torch==$(TORCH_VERSION)"; \
	  else \
	    echo "No NVIDIA GPU: installing the CPU build of torch ($(TORCH_CPU))"; \
	    $(PY) -m pip install -q --no-index --no-deps "$(TORCH_CPU)" 2>/dev/null || \
	      $(PY) -m pip install -q "$(TORCH_CPU)" 2>/dev/null || \
	      { test -n "$(TORCH_CPU_INDEX)" && $(PY) -m pip install "$(TORCH_CPU)" --extra-index-url "$(TORCH_CPU_INDEX)"; } || \
	      { echo "error: no CPU build of torch ($(TORCH_CPU)) in pip's find-links, its indexes or TORCH_CPU_INDEX=$(TORCH_CPU_INDEX);" \
	             "put the wheel in a find-links folder, or set TORCH_CPU_INDEX=URL (an index with torch's CPU builds)" >&2; \
	        exit 1; }; \
	  fi; \
	fi
	$(PY) -m pip install -q -c constraints.txt -e ".[dev]"
	@touch $(STAMP)

lock: install
	@{ echo "# Versions the test suite passed with; \`make install\` installs with \`-c constraints.txt\`."; \
	   echo "# torch is left to the Makefile (CPU or CUDA build); regenerate with \`make lock\`."; \
	   $(PY) -m pip freeze --exclude-editable | grep -v -i -E '^(torch|samp)=='; } > constraints.txt.new
	@mv constraints.txt.new constraints.txt && echo "wrote constraints.txt ($$(grep -c '==' constraints.txt) packages)"

# The main job end to end on CPU: builds the quickstart dataset and the small robot SDF when missing (reused
# by content id afterwards), trains the SAMP policy, evaluates it beside the expert and the straight line,
# and prints the table and the paths of the run folder, its Rerun recording and its plots.
demo: install
	$(PY) -m samp.train experiment=quickstart

test: install
	$(PY) -m pytest -q --durations=15

test-fast: install
	$(PY) -m pytest -q -m "not slow"

bench: install
	$(PY) tools/bench.py robot --out runs/bench/robot.json

# The documentation site (mkdocs.yml, docs/): built strictly into site/ (a broken link, anchor or
# reference fails the build), or served with live reload on http://127.0.0.1:8000.
docs: install
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict

docs-serve: install
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs serve

# samp's disk cache (robot points, anchor grids, compiled kernels): $SAMP_CACHE_DIR, else ~/.cache/samp.
clean-cache:
	rm -rf "$${SAMP_CACHE_DIR:-$${XDG_CACHE_HOME:-$$HOME/.cache}/samp}"
