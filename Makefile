# tiltrov_ros: the two commands a user needs are `make demo` and `make test`.
# Both create the virtual environment .venv/ (real rclpy from PyPI's ROS 2
# Jazzy wheels) when it is absent or out of date.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
TF2_STAMP := $(VENV)/.tf2_msgs
OUT    ?= runs/demo

# DDS isolation for the commands run from here: stay on this machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export MPLBACKEND ?= Agg

.PHONY: install tf2-msgs ros2-cli demo test test-fast lint typecheck bench bench-all soak stress figures docs campaign clean help

# The real ros2 command line (ros2cli, launch, launch_ros as wheels, with an install.sh)
# for the tests that drive the package as a ROS user does: installed into .venv by
# `make ros2-cli` when the folder exists (relative paths: from this directory).
TILTROV_ROS2_CLI ?= ../shared/ros2-cli

help:
	@echo "make demo     run the full stack on the paper's positioning scenario (bag, figures, metrics)"
	@echo "make test     lint, type-check and run the whole test suite"
	@echo "make test-fast the core and analysis tests without ROS and without the slow ones"
	@echo "make install  create .venv with rclpy (ROS 2 Jazzy wheels) and this package"
	@echo "make tf2-msgs build tf2_msgs (/tf) into .venv again (make install does it once)"
	@echo "make ros2-cli add the ros2 command line to .venv (from TILTROV_ROS2_CLI, if present)"
	@echo "make bench    the hot path's targets: each figure compiled and numpy reference, fresh processes"
	@echo "make bench-all every benchmark (speed ratios against baselines measured in the same run)"
	@echo "make soak     one hour of simulated time in lockstep (not part of make test)"
	@echo "make stress   what only wall time under load can judge, beside busy loops (a report)"
	@echo "make figures  regenerate the results page (docs/results.md) and its figures"
	@echo "make docs     regenerate docs/parameters.md and urdf/tiltrov.urdf from the code"
	@echo "make campaign a small random station-keeping campaign on a local Dask cluster"

install: $(STAMP) $(TF2_STAMP)

$(STAMP): setup.py setup.cfg package.xml requirements/ros-jazzy.txt requirements/constraints.txt
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c requirements/constraints.txt \
		-r requirements/ros-jazzy.txt -e '.[bags,campaign,dev]'
	@# colcon must never crawl into the venv (the ROS wheels ship package.xml files).
	@touch $(VENV)/COLCON_IGNORE
	@# Compile the kernels now, so that no node and no first run waits for numba.
	$(VENV)/bin/tiltrov warmup
	@touch $(STAMP)

# tf2_msgs (the type of /tf) has no wheel: built from tools/tf2_msgs with the message
# toolchain of requirements/ros-jazzy-interfaces.txt when the venv cannot import it
# (needs cmake and a C/C++ compiler; without them the stack runs without /tf).
$(TF2_STAMP): $(STAMP) tools/build_tf2_msgs.sh tools/tf2_msgs/CMakeLists.txt \
		tools/tf2_msgs/package.xml tools/tf2_msgs/msg/TFMessage.msg \
		requirements/ros-jazzy-interfaces.txt
	@bash tools/build_tf2_msgs.sh $(VENV)
	@touch $@

tf2-msgs: $(STAMP)
	@bash tools/build_tf2_msgs.sh $(VENV)

ros2-cli: $(STAMP)
	@if [ -f "$(TILTROV_ROS2_CLI)/install.sh" ]; then \
		bash "$(TILTROV_ROS2_CLI)/install.sh" $(VENV); \
	else \
		echo "no ros2 command line at TILTROV_ROS2_CLI=$(TILTROV_ROS2_CLI): the tests with the real ros2 are skipped"; \
	fi

demo: $(STAMP) $(TF2_STAMP)
	$(VENV)/bin/tiltrov demo --out $(OUT)

lint: $(STAMP)
	$(VENV)/bin/ruff check tiltrov_ros test bench launch
	$(VENV)/bin/mypy

# Tests run derandomized (the same Hypothesis examples every run): see test/conftest.py.
# On TEST_WORKERS workers (pytest-xdist), each with its own DDS domain; test/conftest.py
# says which tests share a worker.
TEST_WORKERS ?= 2
PYTEST := TILTROV_HYPOTHESIS_PROFILE=ci $(VENV)/bin/pytest -n $(TEST_WORKERS) --dist loadgroup
test: lint $(TF2_STAMP)
	$(PYTEST)

# The edit loop: the core and the analysis, no ROS process, not the slow tests.
test-fast: $(STAMP)
	$(PYTEST) -q -m 'not slow' test/core test/analysis

bench: $(STAMP)
	$(VENV)/bin/tiltrov bench targets

bench-all: $(STAMP)
	$(VENV)/bin/tiltrov bench

soak: $(STAMP)
	$(VENV)/bin/tiltrov soak

# Realtime tracking, launch wall times and recorded runs beside CPU-bound busy loops:
# judged against wall time on a loaded machine, so reported here, never asserted in tests.
stress: $(STAMP)
	$(PY) bench/stress.py

figures: $(STAMP)
	$(VENV)/bin/tiltrov report --page docs/results.md

docs: $(STAMP)
	$(PY) -m tiltrov_ros.nodes.parameter_docs docs/parameters.md
	$(PY) -m tiltrov_ros.core.robot_description urdf/tiltrov.urdf

# A small version by default; `make campaign SAMPLES=200 CAMPAIGN_OUT=runs/camp` for the
# real one. --resume: run again, it only finishes what is missing and re-summarizes.
SAMPLES      ?= 8
CAMPAIGN_OUT ?= runs/campaign-$(SAMPLES)
campaign: $(STAMP)
	$(VENV)/bin/tiltrov campaign config/campaigns/station_keeping.yaml --samples $(SAMPLES) \
		--out $(CAMPAIGN_OUT) --resume

clean:
	rm -rf $(VENV) build install log .pytest_cache .mypy_cache .ruff_cache runs
