# Two entry points: `make demo` (the main job) and `make test`. Both build .venv themselves.
# `make docs` builds the documentation site (docs/, mkdocs.yml) into build/site.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The interface packages (system_modes_msgs, py_trees_ros_interfaces): built (once per source hash,
# cached under ~/.cache/sm_bt/wheels/) and installed into the venv by tools/ensure_interfaces.sh.
ROS_IFACE_SRCS := $(wildcard interfaces/*/*.txt interfaces/*/*.toml interfaces/*/*.xml interfaces/*/msg/* \
	interfaces/*/srv/* interfaces/*/action/*)

# ROS 2 (rclpy) environment for every recipe: discovery on this host only, logs under build/.
# ROS_DOMAIN_ID is chosen per run by the Python code.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export ROS_LOG_DIR := $(CURDIR)/build/ros_log

.PHONY: demo test lint docs clean

$(STAMP): pyproject.toml constraints.txt $(ROS_IFACE_SRCS) tools/ensure_interfaces.sh tools/install_packages.sh \
		sm_bt/view/assets.py
	@echo "sm_bt: creating $(VENV) and installing the pinned dependencies (ROS 2 Jazzy wheels included; 15-30 s, minutes where the interface packages are built) ..."
	$(PYTHON) -m venv --without-pip $(VENV)
	bash tools/install_packages.sh $(VENV) test,ros,docs
	@echo "sm_bt: dependencies installed; now the interface packages (built once, then cached)"
	bash tools/ensure_interfaces.sh $(VENV)
	$(BIN)/python -m sm_bt.view.assets
	@# The project's own modules, byte-compiled once: with PYTHONDONTWRITEBYTECODE=1 (as on CI machines)
	@# every process would compile them again (a stale .pyc is never used: Python checks the source).
	$(BIN)/python -m compileall -q sm_bt behaviours trees bench tests/support
	touch $@

demo: $(STAMP)
	@mkdir -p $(ROS_LOG_DIR)
	$(BIN)/sm-bt demo

# The same demo on real ROS 2 lifecycle nodes (a child process) with the manager on ROS 2.
.PHONY: demo-ros
demo-ros: $(STAMP)
	@mkdir -p $(ROS_LOG_DIR)
	$(BIN)/sm-bt demo --ros

# The suite in PYTEST_WORKERS parallel workers (pytest-xdist), with Chromium installed while the venv
# is built, and lint and the documentation's build alongside; prints the wall time of each step
# (tools/run_tests.sh).
PYTEST_WORKERS ?= 5
test:
	@mkdir -p $(ROS_LOG_DIR)
	@MAKE="$(MAKE)" VENV="$(VENV)" STAMP="$(STAMP)" PYTEST_WORKERS="$(PYTEST_WORKERS)" bash tools/run_tests.sh

# The manager's property tests (tests/engine/test_manager_properties.py) and the loader's fuzz tests
# (tests/model/test_model_fuzz.py) with the hypothesis `stress` profile: at least 10,000 scenarios and
# 100,000 model files (and 2,000 generated models analysed by sm-bt analyze), then a summary (requests by outcome, recoveries, rules, files by outcome);
# 10,000 scenarios of a simulated fleet with cuts and heals (tests/sim/test_sim_fleet.py),
# 30 partition/heal cycles across two hosts (tests/e2e/stress_partitions.py: network namespaces, root),
# a cut and a heal as the CLI sees them from the brain side (tests/e2e/stress_hosts.py),
# and as many between a fleet's manager and a robot's (tests/e2e/stress_fleet_partitions.py),
# a fleet of ten robots each in a network namespace of its own, its goals measured (tests/e2e/stress_fleet_hosts.py),
# a robot's manager killed during a fleet's change and started again (tests/e2e/stress_fleet_restarts.py),
# nodes whose transitions take 30 s brought up over ROS 2, and a fleet over robots whose nodes take 10 s
# (tests/e2e/stress_long_transitions.py), and
# 10,000 interleavings of subscriptions and changes on the manager's topics (tests/ros/test_ros_topics_property.py).
.PHONY: stress
stress: $(STAMP)
	@mkdir -p $(ROS_LOG_DIR)
	SM_BT_TESTS_NEED_ALL=1 SM_BT_HYPOTHESIS_PROFILE=stress PYTHONPATH=tests/support \
		$(BIN)/python -m pytest -q -s -p stress_summary --timeout=0 -o faulthandler_timeout=0 \
		tests/engine/test_manager_properties.py tests/engine/test_preview.py tests/engine/test_rollback.py \
		tests/engine/test_holds.py tests/analysis/test_analysis.py tests/model/test_model_fuzz.py \
		tests/sim/test_sim_fleet.py tests/e2e/stress_partitions.py tests/e2e/stress_fleet_partitions.py \
		tests/e2e/stress_long_transitions.py tests/ros/test_ros_topics_property.py tests/e2e/stress_hosts.py \
		tests/e2e/stress_fleet_hosts.py tests/e2e/stress_fleet_restarts.py

# The performance goals (docs/performance.md): a table with each goal, build/bench/results.json
# and build/bench/scaling.png; exit status 1 if a goal is not met. About 8 minutes on 2 cores.
.PHONY: bench
bench: $(STAMP)
	@mkdir -p $(ROS_LOG_DIR)
	$(BIN)/python -m bench

# sm-bt manager side by side with the reference's mode_manager (micro-ROS/system_modes, C++), built by
# tools/reference/build.sh once per source hash (about 10 minutes the first time; cached under
# ~/.cache/sm_bt/reference/): the same plain-rclpy scenarios on both, a side-by-side report in
# build/interop/report.md (docs/reference.md, "sm_bt and the reference, measured"), then every CLI
# example of the documentation against the reference, and a fleet manager over a robot the reference
# serves beside one sm-bt manager serves (tests/interop/interop_fleet.py). Exit status 1 if sm-bt
# manager does not do what a scenario asks.
# Without access to github.com, SM_BT_GIT_MIRRORS names a folder of git mirrors of the sources.
# Then py_trees_ros 2.2.2 and devel, from their sources (tools/py_trees_ros.sh): the docs' recipe for
# hosting a mission in py_trees_ros, and py-trees-blackboard-watcher on the trees sm_bt hosts.
.PHONY: interop
interop: $(VENV)/.interop
	@mkdir -p $(ROS_LOG_DIR) build/interop
	prefix="$$(bash tools/reference/build.sh)" && \
	SM_BT_REFERENCE="$$prefix" PYTHONPATH=tests/support:tests/interop \
		$(BIN)/python tests/interop/harness.py --out build/interop && \
	SM_BT_REFERENCE="$$prefix" SM_BT_TESTS_NEED_ALL=1 PYTHONPATH=tests/support \
		$(BIN)/python -m pytest -q -p no:cacheprovider --timeout=600 tests/interop/interop_cli.py tests/interop/interop_fleet.py \
		tests/interop/interop_py_trees_ros.py

$(VENV)/.interop: $(STAMP) pyproject.toml constraints.txt
	bash tools/install_packages.sh $(VENV) interop
	touch $@

# mypy and griffe (the API reference's reader) cannot follow the editable install's mapping of
# behaviours/, trees/ and models/ onto sm_bt.*, so they read a symlinked view of the installed
# layout: $(call installed_layout,DIR) makes DIR/sm_bt.
define installed_layout
	rm -rf $(1) && mkdir -p $(1)/sm_bt
	for f in sm_bt/*; do ln -s "$(CURDIR)/$$f" $(1)/sm_bt/; done
	ln -s "$(CURDIR)/behaviours" $(1)/sm_bt/behaviours
	ln -s "$(CURDIR)/trees" $(1)/sm_bt/trees
	ln -s "$(CURDIR)/models" $(1)/sm_bt/models
endef
TYPECHECK := build/typecheck

lint: $(STAMP)
	$(BIN)/ruff check sm_bt behaviours trees models tests bench tools/docs
	$(call installed_layout,$(TYPECHECK))
	ln -s "$(CURDIR)/bench" $(TYPECHECK)/bench
	cd $(TYPECHECK) && $(CURDIR)/$(BIN)/mypy --config-file $(CURDIR)/pyproject.toml -p sm_bt -p bench

# The documentation site: docs/*.md, README.md as its home page, and an API reference read from the
# docstrings (mkdocstrings, through build/docs/src), built into build/site with warnings as errors.
# NO_MKDOCS_2_WARNING: mkdocs-material's notice about MkDocs 2.0, printed on every build.
docs: $(STAMP)
	$(call installed_layout,build/docs/src)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

clean:
	rm -rf $(VENV) build *.egg-info
