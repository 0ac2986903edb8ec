# galvo_sysid: the two commands are `make demo` and `make test`; both set everything up.
# Set-up is incremental: each step re-runs only when its inputs change (stamp files in .venv).

PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python
# Environment for building the interface package against the venv's ROS 2 wheels.
ROS_BUILD_ENV := PATH=$(CURDIR)/$(VENV)/bin:$$PATH AMENT_PREFIX_PATH=$(CURDIR)/$(VENV) \
                 CMAKE_PREFIX_PATH=$(CURDIR)/$(VENV)
MSG_SRC := $(wildcard msg_defs/msg/*.msg) msg_defs/CMakeLists.txt msg_defs/package.xml

.PHONY: setup demo test lint bench clean

setup: $(VENV)/.pkg-stamp $(VENV)/.pyc-stamp

$(VENV)/.deps-stamp: requirements.txt constraints.txt
	test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	touch $(VENV)/COLCON_IGNORE
	$(VPY) -m pip install --quiet --disable-pip-version-check --no-compile -r requirements.txt \
	    -c constraints.txt
# The dependencies' bytecode, which pip writes in one process, in one per core (-j 0).
	$(VPY) -m compileall -q -j 0 $(VENV)/lib/python3*/site-packages
	$(VPY) tools/fix_cmake_paths.py
	touch $@

$(VENV)/.msgs-stamp: $(VENV)/.deps-stamp $(MSG_SRC)
	mkdir -p build && touch build/COLCON_IGNORE
	$(ROS_BUILD_ENV) $(VENV)/bin/colcon --log-base build/log build --base-paths msg_defs \
	    --merge-install --install-base $(VENV) --build-base build/msgs \
	    --event-handlers console_cohesion- status- summary+ \
	    --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE=$(CURDIR)/$(VPY)
	$(VPY) -c "from galvo_sysid_msgs.msg import ModalParameters, MoveSamples, DriftStatus"
	touch $@

$(VENV)/.pkg-stamp: $(VENV)/.msgs-stamp setup.py setup.cfg package.xml
	$(VPY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation --use-pep517 -e .
	touch $@

# The package's bytecode, as a normal (not editable) pip install writes it: every process
# start then reads the modules' compiled code instead of compiling ~80 modules (0.1 s here,
# where PYTHONDONTWRITEBYTECODE is set). Re-made when a source changes; a stale file is
# never used (Python checks each source's time and size).
PKG_SRC := $(shell find galvo_sysid -name '*.py')
$(VENV)/.pyc-stamp: $(VENV)/.pkg-stamp $(PKG_SRC)
	$(VPY) -m compileall -q galvo_sysid $(VENV)/lib/python3*/site-packages/galvo_sysid_msgs
	touch $@

demo: setup
	$(VPY) -m galvo_sysid.field.demo

# Two worker processes (pytest-xdist), each module's tests on one of them; each worker has
# a ROS domain of its own (test/conftest.py).
test: setup
	$(VPY) -m pytest -q -n 2 --dist loadscope test

lint: setup
	$(VENV)/bin/ruff check galvo_sysid test benchmarks tools launch
	$(VENV)/bin/mypy galvo_sysid

# Speed and accuracy figures (tables on stdout; latest output in docs/benchmarks.md).
BENCHMARKS := accuracy scanner_family paper_pipeline simulator_speed offline_speed offline_warm \
              sysid_throughput sysid_load discrepancy_confusion sysid_hostile_input dither_gain \
              efficiency pooled_efficiency fit_stages independent_scanners handover_speed
bench: setup
	set -e; for b in $(BENCHMARKS); do echo "== benchmarks/$$b.py"; $(VPY) benchmarks/$$b.py; done

clean:
	rm -rf build install log $(VENV)
