# Two entry points for a fresh machine: `make train` and `make test`.
# Both create .venv when missing and install the package (with its dev and all optional extras)
# into it.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.gcnt-installed

.PHONY: train test test-slow test-bench test-gpu-emulated test-slurm lint install clean-venv

install: $(STAMP)

# The versions gcnt is tested with: constraints.txt (pyproject.toml states the ranges it accepts).
$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	# torch first and pinned (constraints.txt: torch==2.13.0): the CPU wheel; an unpinned torch
	# would pull GBs of CUDA packages.
	$(BIN)/pip install -q -c constraints.txt torch
	$(BIN)/pip install -q -c constraints.txt -e ".[dev,all]"
	touch $(STAMP)

train: $(STAMP)
	$(BIN)/gcnt train recipes/quickstart.yaml

# The suite without its end-to-end runs of many seconds (marked slow): about 5 minutes on an
# idle 2-core machine.
test: $(STAMP)
	$(BIN)/python -m pytest -m "not slow and not bench"

# The end-to-end runs (sweeps, signals, worker deaths, plugins, the wheel), then (in a process of
# its own, so that no earlier test's state reaches it) the Slurm checks: as root they install
# slurm-wlm and munge (apt-get) and check sweeps against a single-node Slurm they start
# (tests/test_slurm.py; skipped, saying why, elsewhere). CI runs it after `make test`.
test-slow: $(STAMP)
	$(BIN)/python -m pytest -m "slow and not slurm and not bench"
	$(BIN)/python -m pytest -m slurm tests/test_slurm.py

# gcnt bench-train on every shipped recipe with a tiny budget (tests/test_bench_every_recipe.py):
# a few minutes, so apart from the suite; CI runs it after `make test`.
test-bench: $(STAMP)
	$(BIN)/python -m pytest -m bench tests/test_bench_every_recipe.py

# The whole GPU matrix (tests/test_gpu.py, every method and switch, and the graphed-step parity):
# on the GPU where there is one, else on the emulated GPU of tests/cuda_emulation, whose rules are
# checked first. `make test` runs a subset of it.
test-gpu-emulated: $(STAMP)
	$(BIN)/python -m pytest --gpu-matrix tests/test_cuda_emulation.py tests/test_gpu.py \
		tests/test_gpu_parity.py tests/test_compile_capture.py

# Only the Slurm checks.
test-slurm: $(STAMP)
	$(BIN)/python -m pytest -m slurm tests/test_slurm.py

lint: $(STAMP)
	$(BIN)/ruff check src tests

clean-venv:
	rm -rf $(VENV)
