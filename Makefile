# Two commands for a newcomer: `make demo` and `make test`. Both bootstrap .venv first
# (Python 3.11, pinned wheels, the roger_interfaces messages built with cmake, the
# packages installed editable). The bootstrap is stamp-driven: seconds when nothing changed.
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
.DEFAULT_GOAL := help

PYTHON_BOOT ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMPS := $(VENV)/.stamps
ROOT := $(abspath .)
# pip's extra-index configuration on these machines prints one warning per package.
PIPQUIET := grep -v "is ignored: it is neither a file nor a directory" || true
PACKAGES := roger_common roger_sim roger_perception roger_memory roger_attention \
  roger_experiments roger_bringup
MSG_FILES := $(wildcard src/roger_interfaces/msg/*.msg src/roger_interfaces/srv/*.srv)
SETUP_FILES := $(foreach p,$(PACKAGES),src/$(p)/setup.py)

.PHONY: help bootstrap demo test lint bench clean

help:
	@echo "make demo   run the main experiment (creates .venv on first use)"
	@echo "make test   run the test suite"
	@echo "make lint   ruff, the import contracts (.importlinter) and mypy"
	@echo "make bench  run the benchmarks (see README)"

bootstrap: $(STAMPS)/packages

$(STAMPS)/requirements: requirements.txt
	@test -x $(PY) || { echo "creating $(VENV) with $(PYTHON_BOOT)"; $(PYTHON_BOOT) -m venv $(VENV); }
	@echo "installing pinned requirements into $(VENV) (about a minute the first time)"
	@$(PY) -m pip install -q --disable-pip-version-check -r requirements.txt 2>&1 | $(PIPQUIET)
	@$(PY) -c "import rclpy, pybullet, cv2, torch, yaml" 2>/dev/null || { echo "bootstrap: the pinned install is incomplete; see the pip output above"; exit 1; }
	@mkdir -p $(STAMPS) && touch $@

$(STAMPS)/interfaces: $(STAMPS)/requirements src/roger_interfaces/CMakeLists.txt src/roger_interfaces/package.xml $(MSG_FILES)
	@echo "building roger_interfaces (messages) into $(VENV)"
	@mkdir -p build
	@export AMENT_PREFIX_PATH=$(ROOT)/$(VENV) PATH=$(ROOT)/$(VENV)/bin:$$PATH; \
	  cmake -S src/roger_interfaces -B build/roger_interfaces -Wno-dev \
	    -DCMAKE_PREFIX_PATH=$(ROOT)/$(VENV) -DCMAKE_INSTALL_PREFIX=$(ROOT)/$(VENV) \
	    -DPython3_EXECUTABLE=$(ROOT)/$(PY) -DBUILD_TESTING=OFF > build/interfaces-configure.log 2>&1 \
	  || { echo "cmake configure failed: see build/interfaces-configure.log"; tail -20 build/interfaces-configure.log; exit 1; }; \
	  cmake --build build/roger_interfaces -j2 > build/interfaces-build.log 2>&1 \
	  || { echo "cmake build failed: see build/interfaces-build.log"; tail -30 build/interfaces-build.log; exit 1; }; \
	  cmake --install build/roger_interfaces > build/interfaces-install.log 2>&1
	@$(PY) -c "from roger_interfaces.msg import RoiArray" || { echo "roger_interfaces does not import"; exit 1; }
	@touch $@

# ROS 2 Jazzy's tf2_msgs (/tf, /tf_static): no wheel has it, so its standard definitions
# (third_party/tf2_msgs) are built into the venv the same way.
TF2_FILES := $(wildcard third_party/tf2_msgs/*/*.msg third_party/tf2_msgs/*/*.srv \
  third_party/tf2_msgs/*/*.action)
$(STAMPS)/tf2_msgs: $(STAMPS)/requirements third_party/tf2_msgs/CMakeLists.txt third_party/tf2_msgs/package.xml $(TF2_FILES)
	@echo "building tf2_msgs (ROS 2 Jazzy's definitions) into $(VENV)"
	@mkdir -p build
	@export AMENT_PREFIX_PATH=$(ROOT)/$(VENV) PATH=$(ROOT)/$(VENV)/bin:$$PATH; \
	  cmake -S third_party/tf2_msgs -B build/tf2_msgs -Wno-dev \
	    -DCMAKE_PREFIX_PATH=$(ROOT)/$(VENV) -DCMAKE_INSTALL_PREFIX=$(ROOT)/$(VENV) \
	    -DPython3_EXECUTABLE=$(ROOT)/$(PY) -DBUILD_TESTING=OFF > build/tf2_msgs-configure.log 2>&1 \
	  || { echo "cmake configure failed: see build/tf2_msgs-configure.log"; tail -20 build/tf2_msgs-configure.log; exit 1; }; \
	  cmake --build build/tf2_msgs -j2 > build/tf2_msgs-build.log 2>&1 \
	  || { echo "cmake build failed: see build/tf2_msgs-build.log"; tail -30 build/tf2_msgs-build.log; exit 1; }; \
	  cmake --install build/tf2_msgs > build/tf2_msgs-install.log 2>&1
	@$(PY) -c "from tf2_msgs.msg import TFMessage" || { echo "tf2_msgs does not import"; exit 1; }
	@touch $@

$(STAMPS)/packages: $(STAMPS)/interfaces $(STAMPS)/tf2_msgs $(SETUP_FILES)
	@echo "installing the roger packages (editable) into $(VENV)"
	@$(PY) -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation --use-pep517 \
	  $(foreach p,$(PACKAGES),-e src/$(p)) 2>&1 | $(PIPQUIET)
	@touch $@

# Foxglove's JavaScript bag readers and WebSocket client at the versions of
# test/js/package-lock.json, for test/test_bag_readers.py and test/test_foxglove.py (only
# `make test` needs Node.js and npm).
$(STAMPS)/npm: test/js/package.json test/js/package-lock.json
	@command -v npm >/dev/null || { echo "bootstrap: npm (Node.js 20) is needed by make test for Foxglove's bag readers and WebSocket client"; exit 1; }
	@echo "installing Foxglove's bag readers and WebSocket client into test/js/node_modules (npm ci)"
	@npm ci --prefix test/js --no-audit --no-fund --loglevel=error
	@mkdir -p $(STAMPS) && touch $@

demo: bootstrap
	$(VENV)/bin/roger demo

test: bootstrap $(STAMPS)/npm
	@$(PY) -m pytest -q test

lint: bootstrap
	$(VENV)/bin/ruff check src test bench
	$(VENV)/bin/lint-imports --no-cache
	$(VENV)/bin/mypy

bench: bootstrap
	$(VENV)/bin/roger bench --out runs/bench

clean:
	rm -rf build runs
