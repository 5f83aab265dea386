# CIML — the two commands of the README:
#   make demo   installs what is missing, then runs the demo pipeline
#   make test   installs what is missing, then runs the whole test suite
SHELL := /bin/bash
PY := .venv/bin/python

# DDS discovery stays on this machine for every ROS process started from here.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
# One DDS domain per make invocation, so parallel runs do not see each other (valid ids: 1..101).
ROS_DOMAIN_ID ?= $(shell echo $$(( ($$$$ % 100) + 1 )))
export ROS_DOMAIN_ID

.PHONY: install demo test test-fast bench clean

install:
	@tools/install.sh

demo: install
	@tools/demo.sh

# Two phases: the tests without a ROS graph on every core (a file per worker, so a module's fixture
# is built once), then the ROS tests one at a time (a graph needs both cores of this machine; beside
# other tests it slows more than they gain). Both phases run; the first failure's code is returned.
PYTEST_PHASES = $(PY) -m pytest -q -n auto --dist loadfile -m "not ros$(1)"; a=$$?; \
	$(PY) -m pytest -q -m "ros$(1)"; b=$$?; exit $$(( a ? a : b ))

test: install
	$(call PYTEST_PHASES,)

test-fast: install
	$(call PYTEST_PHASES, and not slow)

bench: install
	.venv/bin/ciml bench --out out/bench.json

clean:
	rm -rf build out
