"""A probe of a live graph (benchmarks and tests): rates, feedback effort, base height, /diagnostics.

GraphProbe watches the graph from a private rclpy context spun in a background thread, on the
caller's DDS domain; the benchmarks that start a graph from its launch file live in the package
that ships the file. The probe itself costs CPU on the same machine: rates
measured with it are a lower bound.
"""
from __future__ import annotations

import os
import threading
import time
from collections import defaultdict
from collections.abc import Callable

import numpy as np

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.learning import rollback
from ciml_learning.ros.executor import DirectExecutor
from ciml_learning.ros.realtime import set_fifo_priority, set_nice, stat_fields, thread_ids


def feedback_effort(cmd: cv.TorqueCommandArrays, q: np.ndarray, qd: np.ndarray) -> float:
    """‖u_fb,pd + u_fb,lin‖ [Nm] of one command on the joint sample (q, q̇) it was computed for
    (rollback.feedback_effort: the law the controller's rollback watch uses too)."""
    return rollback.feedback_effort(cmd.stiffness, cmd.damping, cmd.position_target, cmd.velocity_target,
                                    cmd.feedback_linearization, q, qd)


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of a process, all threads [s] (/proc/<pid>/stat), None once it has exited."""
    try:
        fields = stat_fields(pid)
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def period_stats(receipts: np.ndarray, nominal_hz: float) -> dict:
    """Rate and period statistics of receipt times [s] (monotonic)."""
    if len(receipts) < 3:
        return {"messages": int(len(receipts))}
    dt = np.diff(receipts)
    span = receipts[-1] - receipts[0]
    nominal = 1.0 / nominal_hz
    rate = (len(receipts) - 1) / span
    return {
        "messages": int(len(receipts)),
        "rate_hz": round(rate, 1),
        "nominal_hz": nominal_hz,
        "rate_error_pct": round(100.0 * (rate - nominal_hz) / nominal_hz, 1),
        "period_p50_ms": round(1e3 * float(np.percentile(dt, 50)), 3),
        "period_p99_ms": round(1e3 * float(np.percentile(dt, 99)), 3),
        "period_max_ms": round(1e3 * float(dt.max()), 3),
        "jitter_p99_ms": round(1e3 * float(np.percentile(np.abs(dt - nominal), 99)), 3),
    }


class GraphProbe:
    """Watches the live graph from a private rclpy context spun in a background thread.

    Rate topics are taken serialized (raw): only the receipt time is recorded, so the
    probe's own cost stays small. /torque_command, /joint_states and /base_state are
    deserialized for the effort, the damping count and the base height; /diagnostics
    keeps each node's newest counters.
    """

    def __init__(self, rate_topics: dict[str, str] | None = None, effort_robot=None, priority: int = 0,
                 nice: int = 0) -> None:
        """priority > 0: the probe's threads (its spin thread and its DDS threads, not the rest of
        this process, whose children must not inherit it) run SCHED_FIFO at that priority where
        permitted, so what it times is the graph's delivery, not its own wait for the CPU
        (`self.scheduling` says which it got). nice > 0: those threads run at that nice level
        instead, so a probe that decodes 250 Hz topics does not take the CPU from the graph it
        measures. With `effort_robot` (a RobotDescription) the probe
        keeps (stamp [s], feedback_effort) of every MODE_TORQUE command on its joint sample in
        `efforts`, not the messages (hours of them would not fit in memory)."""
        import rclpy
        from ciml_msgs.msg import TorqueCommand
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
        from sensor_msgs.msg import JointState

        before = thread_ids()
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context)  # not this program's argv (e.g. ciml bench's)
        self.node = rclpy.create_node("ciml_graph_probe", context=self.context)
        self.lock = threading.Lock()
        self.recording = False
        self.robot = effort_robot
        self.efforts: list[tuple[float, float]] = []
        self._joint_arrays: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # stamp ns -> (q, q̇), the newest
        self.receipts: dict[str, list[float]] = defaultdict(list)
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.published: dict[str, list[tuple[float, float]]] = defaultdict(list)
        """`<topic>_rate_hz` / `_jitter_p99_ms` of PublishPeriods: (rate, jitter) per window, while recording."""
        self.diag_levels: dict[str, int] = {}
        self.base_z: list[tuple[float, float]] = []       # (stamp [s], z [m])
        self._lowest_z = float("inf")
        self.base_x: list[tuple[float, float]] = []
        self.n_commands = self.n_damping = 0
        self.first_torque_stamp: int | None = None
        self.first_torque_time: float | None = None
        self.base_at_first_torque: tuple[float, float] | None = None
        # best effort takes both reliable and best-effort publishers (sensor topics are either)
        best_effort = qos_profile_sensor_data
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self._subs = []
        for topic, type_name in (rate_topics or {}).items():
            if topic in (topics.TORQUE_COMMAND, topics.JOINT_STATES, topics.BASE_STATE):
                continue
            self._subs.append(self.node.create_subscription(
                _message_class(type_name), topic, self._stamper(topic), best_effort, raw=True))
        self.node.create_subscription(TorqueCommand, topics.TORQUE_COMMAND, self._on_command, reliable)
        self.node.create_subscription(JointState, topics.JOINT_STATES, self._on_joints, best_effort)
        self.node.create_subscription(Odometry, topics.BASE_STATE, self._on_base, best_effort)
        self.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics, reliable)
        self.executor = DirectExecutor(context=self.context)  # a light probe: it shares the machine
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, name="graph-probe", daemon=True)
        self.thread.start()
        self.scheduling = "normal"
        if priority > 0:
            refused = set_fifo_priority(priority, thread_ids() - before)
            self.scheduling = refused or f"SCHED_FIFO {priority}"
        elif nice > 0:
            set_nice(nice, thread_ids() - before)
            self.scheduling = f"nice {nice}"

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def _stamper(self, topic: str) -> Callable[[object], None]:
        return lambda _msg: self._stamp(topic)

    def _stamp(self, topic: str) -> None:
        if self.recording:
            self.receipts[topic].append(time.monotonic())

    def _on_command(self, msg) -> None:
        self._stamp(topics.TORQUE_COMMAND)
        stamp = cv.stamp_to_ns(msg.header.stamp)
        if msg.mode == 0 and self.first_torque_stamp is None:
            self.first_torque_stamp, self.first_torque_time = stamp, time.monotonic()
            self.base_at_first_torque = self.latest_base()  # (x, z) when the controller took over
        if self.recording:
            self.n_commands += 1
            self.n_damping += msg.mode != 0
        if self.robot is not None and msg.mode == 0:
            with self.lock:
                js = self._joint_arrays.get(stamp)
                if js is not None:
                    cmd = cv.torque_command_arrays(self.robot, msg)
                    self.efforts.append((stamp * 1e-9, feedback_effort(cmd, *js)))

    def _on_joints(self, msg) -> None:
        self._stamp(topics.JOINT_STATES)
        if self.robot is not None:
            q, qd, _tau = cv.joint_state_arrays(self.robot, msg)
            with self.lock:
                self._joint_arrays[cv.stamp_to_ns(msg.header.stamp)] = (q, qd)
                while len(self._joint_arrays) > 64:   # a command follows its joint sample within a few
                    del self._joint_arrays[next(iter(self._joint_arrays))]

    def _on_base(self, msg) -> None:
        self._stamp(topics.BASE_STATE)
        p = msg.pose.pose.position
        with self.lock:
            t = cv.stamp_to_ns(msg.header.stamp) * 1e-9
            self.base_z.append((t, p.z))
            self._lowest_z = min(self._lowest_z, p.z)
            self.base_x.append((t, p.x))

    def _on_diagnostics(self, msg) -> None:
        with self.lock:
            for s in msg.status:
                values = {kv.key: kv.value for kv in s.values}
                for key, value in values.items():
                    topic = key.removesuffix("_jitter_p99_ms")
                    if key != topic and self.recording and self.diagnostics.get(s.name, {}).get(key) != value:
                        self.published[topic].append((float(values[f"{topic}_rate_hz"]), float(value)))
                self.diagnostics[s.name] = values
                self.diag_levels[s.name] = s.level[0] if isinstance(s.level, bytes) else int(s.level)

    def node_names(self) -> set[str]:
        return {name for name, _ns in self.node.get_node_names_and_namespaces()}

    def wait_for(self, predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.1)
        return bool(predicate())

    def latest_base(self) -> tuple[float, float] | None:
        """(x, z) of the newest /base_state [m]."""
        with self.lock:
            return (self.base_x[-1][1], self.base_z[-1][1]) if self.base_z else None

    def sim_time(self) -> float:
        """Stamp of the newest /base_state [s] (0 before the first)."""
        with self.lock:
            return self.base_z[-1][0] if self.base_z else 0.0

    def lowest_z(self) -> float:
        """Lowest base height seen [m] (inf before the first)."""
        with self.lock:
            return self._lowest_z

    def counter(self, node: str, key: str) -> float | None:
        with self.lock:
            values = self.diagnostics.get(node) or self.diagnostics.get("/" + node) or {}
        try:
            return float(values[key])
        except (KeyError, ValueError):
            return None

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self.thread.join(timeout=5)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _message_class(type_name: str) -> type:
    """'pkg/msg/Name' → the message class."""
    import importlib

    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


