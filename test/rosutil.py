"""Helpers for tests that start nodes as separate processes (LOCALHOST discovery, own domain)."""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

BIN = os.path.join(sys.prefix, "bin")


def start_node(exe: str, *ros_args: str) -> subprocess.Popen:
    env = dict(os.environ)
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    cmd = [os.path.join(BIN, exe)]
    if ros_args:
        cmd += ["--ros-args", *ros_args]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop(proc: subprocess.Popen) -> str:
    proc.terminate()
    try:
        out, _ = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out or ""


class Listener:
    """Subscribe to topics in a private rclpy context spun in a background thread."""

    def __init__(self, subscriptions: dict[str, type], qos_depth: int = 1000, qos: dict | None = None) -> None:
        """subscriptions: topic -> message class; qos: topic -> QoS profile for topics that are
        not reliable (e.g. sensor topics published best effort); default reliable, qos_depth."""
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("test_listener", context=self.context)
        self.messages: dict[str, list] = {t: [] for t in subscriptions}
        self.received: dict[str, list[float]] = {t: [] for t in subscriptions}  # time.monotonic() per message
        reliable = QoSProfile(depth=qos_depth, reliability=ReliabilityPolicy.RELIABLE)
        for topic, cls in subscriptions.items():
            self.node.create_subscription(cls, topic, lambda m, t=topic: self._receive(t, m),
                                          (qos or {}).get(topic, reliable))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _receive(self, topic: str, message) -> None:
        self.received[topic].append(time.monotonic())
        self.messages[topic].append(message)

    def _spin(self) -> None:
        while not self._stop:
            self.executor.spin_once(timeout_sec=0.05)

    def wait_for(self, predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.05)
        return predicate()

    def close(self) -> None:
        import rclpy

        self._stop = True
        self.thread.join(timeout=5)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def fifo_permitted() -> bool:
    """May this user run a process SCHED_FIFO (root or an rtprio limit)? Asked of a child process."""
    probe = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True).returncode == 0
