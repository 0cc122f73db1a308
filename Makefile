# Set-up and main commands. `make demo` and `make test` work on a fresh clone with only Python 3.10+.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
TORCH_VERSION ?= 2.13.0
# CPU wheels of torch for machines without an NVIDIA GPU (used only when no local wheel is found).
TORCH_CPU_INDEX ?= https://download.pytorch.org/whl/cpu
STAMP := $(VENV)/.samp-installed

.PHONY: install demo test test-fast bench clean-cache

install: $(STAMP)

# torch is installed first and only when missing: on a machine without an NVIDIA GPU we take a local
# CPU wheel if pip's find-links has one (its dependencies come with the package install below), else
# the CPU index, so no CUDA packages are ever pulled there.
$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@if ! $(PY) -c "import torch" >/dev/null 2>&1; then \
	  if command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then \
	    echo "NVIDIA GPU found: installing torch==$(TORCH_VERSION) with CUDA"; \
	    $(PY) -m pip install "torch==$(TORCH_VERSION)"; \
	  else \
	    echo "No NVIDIA GPU: installing the CPU build of torch==$(TORCH_VERSION)"; \
	    $(PY) -m pip install -q --no-index --no-deps "torch==$(TORCH_VERSION)" 2>/dev/null || \
	      $(PY) -m pip install "torch==$(TORCH_VERSION)" --index-url $(TORCH_CPU_INDEX) --extra-index-url https://pypi.org/simple; \
	  fi; \
	fi
	$(PY) -m pip install -q -e ".[dev]"
	@touch $(STAMP)

# The newest end-to-end path: the robot report and a scene report (summaries + Rerun recordings).
demo: install
	$(PY) -m samp.robot show robot=panda out=runs/demo/robot_panda.rrd
	$(PY) -m samp.scene show scene=tabletop seed=3 n_e=64 out=runs/demo/scene_tabletop.rrd

test: install
	$(PY) -m pytest -q

test-fast: install
	$(PY) -m pytest -q -m "not slow"

bench: install
	$(PY) tools/bench.py robot --out runs/bench/robot.json

clean-cache:
	rm -rf .cache
