"""What every CIML node shares: the Jazzy main skeleton, parameters with descriptors,
health counters on /diagnostics. Nodes stay thin adapters around pure modules.
"""
from __future__ import annotations

import os
from collections import Counter
from collections.abc import Callable, Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from . import topics

SENSOR_QOS = qos_profile_sensor_data
"""Sensor topics: best effort, keep last 5 — a late sample is worthless."""
COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
"""Commands, references, model errors: reliable."""


OK, WARN, ERROR = 0, 1, 2
"""diagnostic_msgs/DiagnosticStatus levels (the message field is a byte)."""


def run_node(factory: Callable[[], Node], args: Sequence[str] | None = None) -> None:
    """rclpy.init → spin → clean shutdown (the ros2/demos skeleton).

    DDS discovery defaults to this machine only; set ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET
    explicitly to talk to other hosts.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init(args=args)
    node = None
    try:
        node = factory()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def declare(node: Node, name: str, default, description: str, lo: float | None = None, hi: float | None = None):
    """Declare a parameter with a description and (for numbers) a range; return its value."""
    desc = ParameterDescriptor(description=description)
    if lo is not None and hi is not None:
        if isinstance(default, bool):
            pass
        elif isinstance(default, int):
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        elif isinstance(default, float):
            desc.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    return node.declare_parameter(name, default, desc).value


class Health:
    """Counts events (rejected inputs, fallbacks, …) and publishes them on /diagnostics at 1 Hz."""

    def __init__(self, node: Node, hardware_id: str = "") -> None:
        self.node = node
        self.counts: Counter[str] = Counter()
        self.level = OK
        self.message = "ok"
        self._hardware_id = hardware_id
        self._pub = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        node.create_timer(1.0, self.publish)

    def count(self, event: str, warn: str | None = None) -> None:
        """Count one event; with `warn`, also log it (throttled) and raise the level to WARN."""
        self.counts[event] += 1
        if warn is not None:
            self.level = max(self.level, WARN)
            self.message = warn
            self.node.get_logger().warning(f"{warn} ({event}: {self.counts[event]})", throttle_duration_sec=1.0)

    def set(self, level: int, message: str) -> None:
        self.level, self.message = level, message

    def publish(self) -> None:
        status = DiagnosticStatus(
            level=bytes([self.level]),
            name=self.node.get_fully_qualified_name(),
            message=self.message,
            hardware_id=self._hardware_id,
            values=[KeyValue(key=k, value=str(v)) for k, v in sorted(self.counts.items())],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._pub.publish(msg)
