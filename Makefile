# depthsense — set-up, demo, tests. Every target installs what it needs itself:
# the PyPI wheel torch==2.11.0 (libtorch for tch 0.24) into .venv/, Rust crates via cargo.
#
#   make demo   synthetic world → prepare → train → eval → runs/demo/report/report.html
#   make test   the whole test suite (Rust, the PyTorch references, the nuScenes devkit goldens);
#               its last line lists every skipped test and why
#   make test-browser  `depthsense report`'s page in headless Chromium (installs Debian's chromium)
#   make gpu-bundle  .gpu/: stripped binary (with NCCL) + small prepared world + scripts for
#               scripts/gpu-check.sh and its science step (scripts/gpu-science.sh)
#   make python the Python module `depthsense` (crates/python) built by maturin into .venv

SHELL := /bin/bash
PYTHON ?= python3
TORCH_VERSION := 2.11.0
VENV := $(CURDIR)/.venv
# Bumped when the package list changes, so that an existing .venv gets the new packages.
SETUP_VERSION := 3
STAMP := $(VENV)/.depthsense-setup-$(TORCH_VERSION)-$(SETUP_VERSION)

export VIRTUAL_ENV := $(VENV)
export PATH := $(VENV)/bin:$(PATH)
export LIBTORCH_USE_PYTORCH := 1

CARGO ?= cargo
BIN := target/release/depthsense

# `prerequisites`: setup and python at once (used by demo and test).
.PHONY: prerequisites all setup build install demo test test-browser bench fmt clippy check clean-venv gpu-bundle python

all: build

# The venv's first package: maturin alone (a Rust binary in a wheel, no dependencies), so that
# the torch-free Python module compiles while pip unpacks torch and its CUDA wheels: `make test`
# and `make demo` run the two at once (prerequisites, below).
MATURIN_STAMP := $(VENV)/.depthsense-maturin-$(SETUP_VERSION)
$(MATURIN_STAMP):
	@test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --disable-pip-version-check -q "maturin>=1.9.4,<2"
	@touch $@

# The venv: torch (libtorch + CUDA runtime wheels; runs on CPU-only machines too),
# numpy, the official nuScenes devkit used by the format check of the synthetic world, and
# onnx + onnxruntime for `depthsense export` (its ONNX check and tests), maturin (builds the
# Python module, `make python`) and pytest (its tests). One pip call, so that onnx's ml_dtypes
# is resolved against the devkit's numpy < 2 (a later, separate install of onnx upgrades numpy
# to 2 and breaks the devkit). --no-cache-dir: pip keeps no second copy of the ≈ 3 GB of torch
# and CUDA wheels in ~/.cache/pip (CI's clean clone once ran out of disk during this install,
# 2026-12-05, on a disk shared with other work; the venv itself is 5.4 GB).
$(STAMP): $(MATURIN_STAMP)
	$(VENV)/bin/python -m pip install --disable-pip-version-check --no-cache-dir -q "torch==$(TORCH_VERSION)" "numpy<2" nuscenes-devkit onnx onnxruntime "maturin>=1.9.4,<2" pytest
	@$(VENV)/bin/python -c "import torch; assert torch.__version__.split('+')[0] == '$(TORCH_VERSION)', torch.__version__"
	@touch $@

setup: $(STAMP)

build: setup
	$(CARGO) build --release -p depthsense-cli

# The Python module `depthsense` (crates/python, PyO3, no libtorch): a release wheel built by
# maturin into target/wheels/depthsense and installed into .venv — again whenever a crate's
# source, a Cargo.toml or Cargo.lock changes (cargo rebuilds only what the module is built
# from). `make test` and `make demo` run it.
PY_WHEELS := target/wheels/depthsense
# `make test` builds the module with the dev profile (optimised, as the workspace's dev profile
# is): it then shares its dependencies' build with `cargo test` instead of compiling them a
# second time for release (about 2.5 minutes on a clean clone of a 2-core machine).
PY_PROFILE ?= --release
PY_STAMP := $(VENV)/.depthsense-python
PY_WHEEL_STAMP := target/wheels/.depthsense-built
PY_SOURCES := $(shell find crates -path '*/src/*.rs' -o -name Cargo.toml -o -name pyproject.toml) Cargo.toml Cargo.lock

# The wheel needs maturin and the venv's interpreter only, not torch.
$(PY_WHEEL_STAMP): $(MATURIN_STAMP) $(PY_SOURCES)
	rm -rf $(PY_WHEELS)
	$(VENV)/bin/maturin build $(PY_PROFILE) --quiet -i $(VENV)/bin/python -m crates/python/Cargo.toml --out $(PY_WHEELS)
	@touch $@

$(PY_STAMP): $(STAMP) $(PY_WHEEL_STAMP)
	$(VENV)/bin/python -m pip install --disable-pip-version-check -q --force-reinstall --no-deps $(PY_WHEELS)/depthsense-*.whl
	@touch $@

python: $(PY_STAMP)

# pip's install of torch (one core: unpacking ≈ 3 GB) and the Python module's compile (both
# cores) at once; then the module into the venv. On a clean clone of the 2-core VM: 68 s + 119 s
# one after the other.
# The sub-makes name phony goals with a silent recipe, so that nothing is printed for files
# that are already up to date.
prerequisites:
	@$(MAKE) --no-print-directory -j2 venv-and-wheel PY_PROFILE=$(PY_PROFILE)
	@$(MAKE) --no-print-directory python-module PY_PROFILE=$(PY_PROFILE)

.PHONY: venv-and-wheel python-module
venv-and-wheel: $(STAMP) $(PY_WHEEL_STAMP)
	@:
python-module: $(PY_STAMP)
	@:

# Both binaries into $(PREFIX)/bin (depthsense-net must stay beside depthsense; it finds
# libtorch in this checkout's .venv through its rpath).
PREFIX ?= $(HOME)/.local
install: build
	install -d $(PREFIX)/bin
	install -m 755 target/release/depthsense target/release/depthsense-net $(PREFIX)/bin/
	@echo "installed depthsense and depthsense-net into $(PREFIX)/bin"
	@case ":$$PATH:" in *":$(PREFIX)/bin:"*) ;; *) echo "$(PREFIX)/bin is not on your PATH: export PATH=$(PREFIX)/bin:\$$PATH";; esac

# A finished demo in runs/demo is never replaced silently: `make demo DEMO_ARGS=--force`.
DEMO_ARGS ?=
demo: prerequisites
	@$(MAKE) --no-print-directory build
	$(BIN) demo --out runs/demo $(DEMO_ARGS)

# The test binaries run with the memory settings `depthsense-net` makes at start (tune_memory
# in crates/cli/src/bin/depthsense-net/main.rs): glibc keeps freed memory and libtorch puts large tensors on huge
# pages, or libtorch's per-layer tensors page-fault in anew every step. Built first without
# them, so that the compiler runs with glibc's defaults.
TEST_MALLOC := glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=1073741824

# Torch and the devkit are installed by `setup`: a test that cannot use them fails (crates/testkit)
# instead of skipping. Every skip that remains is listed on the last line (SKIP_LOG).
SKIP_LOG := $(CURDIR)/target/test-skips.log

# libtorch's OpenMP pool is one thread per test process: the harness already runs one test per
# core, and a second OpenMP thread each oversubscribed the cores with libgomp spinning at every
# parallel region (clean clone, 2-core EPYC VM: the Rust tests 326 s → 264 s wall, 582 → 408
# CPU-seconds; the cli tests 125 s → 72 s). Tests that time threads set them (`--threads`).
TEST_THREADS_ENV := OMP_NUM_THREADS=1

TEST_ENV := $(TEST_THREADS_ENV) GLIBC_TUNABLES=$(TEST_MALLOC) THP_MEM_ALLOC_ENABLE=1 \
  DEPTHSENSE_REQUIRE_DEVKIT=1 DEPTHSENSE_REQUIRE_TORCH=1 DEPTHSENSE_SKIP_LOG=$(SKIP_LOG)
TEST_BINARIES := target/test-binaries.json

# The Rust test binaries run two at once (scripts/run-tests.py: each one's output printed whole
# when it ends, then a count and the failed binaries with the cargo command that reruns them),
# then the doc-tests through cargo. One binary by hand: `cargo test -p CRATE --test NAME`.
# The Python module's tests (pytest, python/tests) run last, with the debug `depthsense` that
# `cargo test` built.
test: PY_PROFILE :=
test: prerequisites
	$(CARGO) test --workspace --no-run --message-format=json-render-diagnostics > $(TEST_BINARIES)
	@rm -f $(SKIP_LOG)
	$(TEST_ENV) $(VENV)/bin/python scripts/run-tests.py $(TEST_BINARIES); rc=$$?; \
	$(TEST_ENV) $(CARGO) test --workspace --doc -q || rc=1; \
	$(TEST_THREADS_ENV) DEPTHSENSE_REQUIRE_TORCH=1 DEPTHSENSE_SKIP_LOG=$(SKIP_LOG) DEPTHSENSE_BIN=$(CURDIR)/target/debug/depthsense \
	  $(VENV)/bin/python -m pytest -q -p no:cacheprovider python/tests || rc=1; \
	scripts/skip-summary.sh $(SKIP_LOG); exit $$rc

# `depthsense report`'s page in headless Chromium (Debian's package; installed with apt-get when
# missing, as root). `make test` skips that test when chromium is absent; here it must run.
test-browser: setup
	command -v chromium >/dev/null || apt-get install -y chromium
	DEPTHSENSE_REQUIRE_BROWSER=1 $(CARGO) test -p depthsense-experiments --test experiments report::

bench: build
	$(BIN) bench data --out runs/bench/data.json
	$(BIN) bench synth --out runs/bench/synth.json
	$(BIN) bench model --out runs/bench/model.json
	$(BIN) bench train --out runs/bench/train.json
	$(BIN) bench export --config tiny --out runs/bench/export-tiny.json

# Everything a GPU machine without Rust needs for scripts/gpu-check.sh (issue 9, ../shared/GPU.md):
# the stripped release binary, a small prepared synthetic world and the scripts, in .gpu/
# (git-ignored, < 64 MiB). On the GPU machine: `bash .gpu/gpu-check.sh`.
# The binary is built with NCCL and CUDA graphs (features nccl and cuda-graphs: ProcessGroupNCCL and
# at::cuda::CUDAGraph against the CUDA and NCCL headers of the torch wheel's nvidia-* packages plus
# libcu++ from nvidia-cuda-cccl, installed here): gpu-check runs one NCCL rank against one process
# and times the replayed graph. The same binary runs on CPU-only machines.
gpu-bundle: setup
	$(VENV)/bin/python -m pip install --disable-pip-version-check -q "nvidia-cuda-cccl==13.0.*"
	$(CARGO) build --release -p depthsense-cli --features depthsense-cli/nccl,depthsense-cli/cuda-graphs
	scripts/gpu-check.sh --make-bundle .gpu

fmt:
	$(CARGO) fmt --all

clippy: setup
	$(CARGO) clippy --workspace --all-targets -- -D warnings

check: fmt clippy test

clean-venv:
	rm -rf $(VENV)
