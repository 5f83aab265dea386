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

test: install
	$(PY) -m pytest -q

test-fast: install
	$(PY) -m pytest -q -m "not slow"

bench: install
	.venv/bin/ciml bench --out out/bench.json

clean:
	rm -rf build out
