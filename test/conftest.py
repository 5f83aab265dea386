"""Each pytest-xdist worker of `make test`'s first phase in a DDS domain of its own (the make
invocation's, offset by the worker's number): a test that starts rclpy in one worker never sees the
other worker's nodes. Set at collection, before any test starts rclpy."""
from __future__ import annotations

import os

_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
if _WORKER.startswith("gw"):
    _BASE = int(os.environ.get("ROS_DOMAIN_ID") or 0)
    os.environ["ROS_DOMAIN_ID"] = str((_BASE + int(_WORKER[2:])) % 101 + 1)  # valid ids: 1..101
