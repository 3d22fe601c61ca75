# Two commands on a fresh machine:  `make run` (the demo on the bundled sample) and `make test`.
# Both create .venv, install the pinned requirements and Debian packages, and build the interfaces,
# each step only when its inputs changed (stamps in .stamps/).

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMPS := .stamps
OUT    ?= out/demo
SAMPLE ?= bags/sim_walking_changing.mcap
PYTEST_ARGS ?=

MSG_SOURCES := $(shell find msg_defs -type f -not -path '*/build/*' 2>/dev/null)

.PHONY: setup run test test-quick orbslam3-venv node-reference clean distclean help

help:
	@echo "make run         run the pipeline on the bundled sample ($(SAMPLE)) into $(OUT)"
	@echo "make test        the whole test suite (make test-quick skips slow system tests)"
	@echo "make orbslam3-venv  ORB-SLAM3's bindings in .venv-orbslam3 for bench/bench_orbslam3.py (GPL, not a dependency)"
	@echo "make node-reference  regenerate docs/nodes.md from the nodes (test/nodes/test_node_reference.py checks it)"
	@echo "make clean       remove build outputs (keeps .venv)"

setup: $(STAMPS)/apt $(STAMPS)/venv $(STAMPS)/interfaces $(STAMPS)/package

$(STAMPS):
	@mkdir -p $(STAMPS)

$(STAMPS)/apt: tools/apt-packages.txt | $(STAMPS)
	tools/install_apt.sh tools/apt-packages.txt
	@touch $@

$(STAMPS)/venv: requirements.txt | $(STAMPS)
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@touch $(VENV)/COLCON_IGNORE  # the venv holds ROS package.xml files colcon must not crawl
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt 2> $(STAMPS)/pip.log || { cat $(STAMPS)/pip.log; exit 1; }
	@touch $@

$(STAMPS)/interfaces: $(STAMPS)/venv tools/build_interfaces.sh $(MSG_SOURCES) | $(STAMPS)
	VIRTUAL_ENV=$(abspath $(VENV)) tools/build_interfaces.sh
	@touch $@

$(STAMPS)/package: $(STAMPS)/venv setup.py setup.cfg | $(STAMPS)
	$(PY) -m pip install --quiet --no-deps --no-build-isolation -e . 2> $(STAMPS)/pip-package.log || { cat $(STAMPS)/pip-package.log; exit 1; }
	@# setup.cfg puts executables where `ros2 run` looks (lib/changing_slam_ros/); link them onto the venv's PATH too.
	@for s in $(VENV)/lib/changing_slam_ros/*; do ln -sf "../lib/changing_slam_ros/$$(basename "$$s")" $(VENV)/bin/; done
	@touch $@

run: setup
	@# The ROS 2 graph (bag_player, detection, tracking, local_mapping, loop_closing, object_map as separate processes) over the sample,
	@# lossless so every frame is processed; prints the ATE and where the outputs are.
	$(PY) -m changing_slam_ros.cli graph $(SAMPLE) --out $(OUT) --config sim --lossless

test: setup
	$(PY) -m pytest -q $(PYTEST_ARGS)

test-quick: setup
	$(PY) -m pytest -q -m "not slow" $(PYTEST_ARGS)

orbslam3-venv:
	@# ORB-SLAM3's Python bindings (GPL-3.0) in a separate venv, for bench/bench_orbslam3.py only; never a dependency.
	@test -x .venv-orbslam3/bin/python || $(PYTHON) -m venv .venv-orbslam3
	.venv-orbslam3/bin/python -m pip install --quiet --disable-pip-version-check pyorbslam3==0.1.1 numpy opencv-python-headless

node-reference: setup
	$(PY) tools/gen_node_reference.py

clean:
	rm -rf build install log .pytest_cache $(STAMPS)/interfaces
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV) $(STAMPS)
