"""ROS conventions a user expects of every CIML node (issue 18 item 5): QoS a default
subscriber matches, /diagnostics that recover, parameters from one schema (reconfigurable or
refused), one-line errors for bad parameters, clean exits on signals, /tf and
/robot_description, shipped layouts, the venv as an ament prefix, /gap_diagnosis."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from rosutil import BIN, Listener, start_node, stop

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# --- /diagnostics that recover -------------------------------------------------------------------


@pytest.fixture
def node_in_private_context():
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("health_test", context=ctx)
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def test_health_condition_raised_then_cleared_returns_to_ok(node_in_private_context):
    from ciml_learning.ros_common import ERROR, OK, WARN, Health

    health = Health(node_in_private_context, event_hold=0.2)
    health.set(OK, "torque control")
    assert health.status().level == bytes([OK]) and health.status().message == "torque control"
    health.condition("stale_state", True, WARN, "base state stale: damping")
    health.condition("qp", True, ERROR, "QP infeasible")
    st = health.status()
    assert st.level == bytes([ERROR]) and st.message == "QP infeasible"  # the worst active condition
    health.condition("qp", False)
    assert health.status().level == bytes([WARN]) and health.status().message == "base state stale: damping"
    health.condition("stale_state", False)
    assert health.status().level == bytes([OK]) and health.status().message == "torque control"
    # a warned event is a condition for `event_hold` seconds after its last occurrence; counts stay
    health.count("rejected_commands", "command rejected: NaN")
    health.count("rejected_commands", "command rejected: NaN")
    assert health.status().level == bytes([WARN]) and "NaN" in health.status().message
    time.sleep(0.3)
    st = health.status()
    assert st.level == bytes([OK]) and st.message == "torque control"
    assert {kv.key: kv.value for kv in st.values} == {"rejected_commands": "2"}
    # the mode itself can be a warning (e.g. the bridge holding the standing pose)
    health.set(WARN, "holding the standing pose")
    assert health.status().level == bytes([WARN])
    health.set(OK, "torque control")
    assert health.status().level == bytes([OK])
