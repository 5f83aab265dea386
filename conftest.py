"""Test-session setup shared by every package's tests.

DDS must never leave the machine, and parallel test runs must not see each other:
every ROS process started by the tests inherits LOCALHOST discovery and this run's
own ROS_DOMAIN_ID (the Makefile picks one per run; a random one otherwise). `make test`
runs the suite in two pytest-xdist workers (`--dist loadgroup`); each worker gets a domain
of its own (the run's + the worker's index), and `pytest_collection_modifyitems` decides
what may run side by side.
"""
import os
import random

import pytest

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)  # deprecated in Jazzy; RANGE is the setting
if not os.environ.get("ROS_DOMAIN_ID"):
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 101))
_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")  # "gw0", "gw1", … under xdist
if _WORKER.startswith("gw"):
    os.environ["ROS_DOMAIN_ID"] = str((int(os.environ["ROS_DOMAIN_ID"]) - 1 + int(_WORKER[2:])) % 101 + 1)

LIVE_GROUP = "live"
"""The xdist group of every test that runs ROS nodes (marker `ros`): they run one after another
on one worker, as the graph's rates and timing assume (two graphs at once need four cores), beside
the other worker's tests."""


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the groups into the test ids
def pytest_collection_modifyitems(config, items):
    """Under xdist (`--dist loadgroup`): the `ros` tests form one group; every other test is
    grouped with its file, so a module's fixtures (recorded bags, fitted models) are built once.
    (xdist 3.8 reads the group into the test id, which pytest 9.2 no longer lets it do: pytest is
    pinned to 9.1.)"""
    if not _WORKER and not getattr(config.option, "numprocesses", None):
        return
    for item in items:
        group = LIVE_GROUP if item.get_closest_marker("ros") else item.nodeid.split("::")[0]
        item.add_marker(pytest.mark.xdist_group(group))
