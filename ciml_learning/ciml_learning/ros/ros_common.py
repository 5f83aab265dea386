"""What every CIML node shares: the Jazzy main skeleton (clean exits, one-line errors),
parameters declared from one schema per node (ciml_learning.core.params), QoS profiles, and
health conditions on /diagnostics that return to OK when they clear.
Nodes stay thin adapters around pure modules (docs/ARCHITECTURE.md).
"""
from __future__ import annotations

import faulthandler
import gc
import os
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, ShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions

from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.ros import realtime
from ciml_learning.ros.executor import DirectExecutor

if TYPE_CHECKING:
    from ciml_learning.core.params import NodeSchema

SENSOR_PUB_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
"""Publishers of sensor topics (/joint_states, /base_state, /contact_state): reliable, so a
subscriber with default QoS (a dashboard, `ros2 topic echo`) matches as well as a best-effort
one; keep-last 10 never blocks the publisher (a slow reader loses the oldest samples)."""
SENSOR_QOS = qos_profile_sensor_data
"""Subscriptions to sensor topics: best effort, keep last 5 — a late sample is worthless, and a
best-effort reader matches both a reliable publisher and a robot driver that publishes best effort."""
COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
"""Commands, references, model errors: reliable (the ROS default profile)."""
STREAM_DEPTH = 250
"""Queue of the state filter's and error extractor's subscriptions and publishers: 1 s at
250 Hz. Every sample matters to the learner and none is urgent, so a learning process that
waited for the CPU (the real-time control path comes first) catches up instead of losing
samples. The online learner has its own `queue_depth` parameter, 1 s as well."""
STREAM_QOS = QoSProfile(depth=STREAM_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
"""The learning chain's own streams (/filtered_state, /model_error/measured, and the state
filter's /torque_command): reliable, deep."""
SENSOR_STREAM_QOS = QoSProfile(depth=STREAM_DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT)
"""The state filter's sensor subscriptions: best effort like SENSOR_QOS (matches any driver),
but deep, so samples are not dropped while the filter waits for the CPU."""
LATEST_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
"""Subscriptions that use only the newest message (the controller's reference and prediction): a
process that falls behind skips to it instead of converting a queue of outdated ones. (The model
server keeps COMMAND_QOS: every reference is answered; it runs SCHED_FIFO 20 so that it keeps up.)"""
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""Published once, kept for late joiners (/robot_description, /tf_static, /gap_diagnosis)."""


GIL_SWITCH_INTERVAL = 0.0005
"""[s] sys.setswitchinterval of node processes. A worker thread (model loading, snapshot
writing) may hold the GIL for Python's default 5 ms before the executor thread gets it back:
longer than a 250 Hz cycle's whole period. (A choice from that reasoning; its effect alone
was not measured.)"""

SHUTDOWN_GRACE = 5.0
"""[s] after SIGINT/SIGTERM before run_node ends a stuck shutdown itself (ros2 launch escalates
to SIGTERM after 5 s)."""
SIGNAL_POLL_PERIOD = 0.1
"""[s] longest wait of a node process's executor: the most a SIGINT/SIGTERM waits to be seen."""
PUBLISH_PERIOD = 1.0
"""[s] between /diagnostics messages of a node (diagnostic_updater's default rate)."""
FIRST_PUBLISH_DELAY = 0.001
"""[s] the first /diagnostics after the node starts spinning."""
OK, WARN, ERROR = 0, 1, 2
"""diagnostic_msgs/DiagnosticStatus levels (the message field is a byte)."""


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


def _node_name(factory: Callable[[], Node]) -> str:
    """IdControllerNode -> id_controller (the logger name of a node that failed to start)."""
    cls = getattr(factory, "__name__", "node").removesuffix("Node")
    return "".join(f"_{c.lower()}" if c.isupper() else c for c in cls).lstrip("_")


def run_node(factory: Callable[[], Node], args: Sequence[str] | None = None, name: str | None = None) -> None:
    """One node in its own process (`ros2 run`): run_nodes with one factory."""
    run_nodes([factory], args, name or _node_name(factory))


def run_nodes(factories: Sequence[Callable[[], Node]], args: Sequence[str] | None = None,
              name: str = "ciml_container") -> None:
    """rclpy.init → spin → clean shutdown (the ros2/demos skeleton), for one node in its own
    process or several composed in one (`ciml_container`), spun by one DirectExecutor
    (ciml_learning.ros.executor: the CPU of a cycle goes to the nodes, not to rebuilding wait sets).

    - SIGINT/SIGTERM: the process handles them itself and rclpy installs no signal handler
      (SignalHandlerOptions.NO). The handler only records the signal; the executor never waits
      longer than SIGNAL_POLL_PERIOD, so the main thread sees the signal within that time, ends
      the spin between two callbacks, destroys its nodes and shuts the context down itself:
      exit status 0, no traceback. Why not rclpy's handlers: they shut the context down from
      rclpy's own signal thread while the executor may still be waiting or in a callback; that
      race raised errors mid-callback (a pybind11 RuntimeError, "Exception ignored" in a
      destructor) and, rarely, left a process that never exited (CI, 2026-11-26: one of ~240
      SIGINTs, the node silent, its Python handler never run).
    - A shutdown still unfinished SHUTDOWN_GRACE after the signal is ended by the process with a
      warning and every thread's stack on stderr (a watchdog thread), exit status 0: a stop
      request always stops the process. If even that thread cannot run (rclpy's node
      destruction blocked in C holding the interpreter lock: 1 in ~20 SIGINT rounds of a loaded
      2-core machine, docs/LIVE_GRAPH.md), faulthandler dumps the stacks a second later without
      the lock and a native timer thread (realtime.exit_after) ends the process with status 0
      half a second after that.
    - A bad parameter (wrong type, out of range, refused by the schema) or a CimlError while
      building a node (bad URDF, scenario, model folder): one logged line, exit status 1.

    DDS discovery defaults to this machine only; set ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET
    explicitly to talk to other hosts.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    signalled: list[int] = []

    def watchdog() -> None:
        time.sleep(SHUTDOWN_GRACE)
        rclpy.logging.get_logger(name).warning(
            f"shutdown not finished {SHUTDOWN_GRACE:g} s after the signal; exiting (stacks on stderr)")
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)

    def on_signal(signum: int, _frame) -> None:
        if not signalled:
            # stacks, then exit 0, even if the shutdown blocks in a C call that holds the GIL
            native = realtime.exit_after(SHUTDOWN_GRACE + 1.5, 0)
            faulthandler.dump_traceback_later(SHUTDOWN_GRACE + 1.0, exit=not native)
            threading.Thread(target=watchdog, name="shutdown_watchdog", daemon=True).start()
        signalled.append(signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    try:
        rclpy.init(args=None if args is None else list(args), signal_handler_options=SignalHandlerOptions.NO)
    except Exception as err:  # malformed --ros-args (rcl parses them here)
        rclpy.logging.get_logger(name).error(f"bad arguments: {_one_line(err)}")
        raise SystemExit(1) from None
    context = rclpy.get_default_context()
    nodes: list[Node] = []
    executor = None
    status = 0
    try:
        executor = DirectExecutor(context=context)
        for factory in factories:
            if signalled:
                break
            nodes.append(factory())
            executor.add_node(nodes[-1])
        # what the nodes built (robot models, compiled kernels, imports) is never garbage: keep
        # it out of the collector's generations, so a cyclic collection during the loop is short
        gc.collect()
        gc.freeze()
        sys.setswitchinterval(GIL_SWITCH_INTERVAL)
        if nodes and not signalled:
            _schedule(nodes, name)
        while not signalled and context.ok():
            executor.spin_once(timeout_sec=SIGNAL_POLL_PERIOD)
    except (ExternalShutdownException, ShutdownException):
        pass
    except (ParameterException, CimlError) as err:
        if not signalled:
            rclpy.logging.get_logger(name).error(f"{_one_line(err)}")
            status = 1
    finally:
        try:
            for node in nodes:
                node.destroy_node()
            if executor is not None:
                executor.shutdown(timeout_sec=0)
            rclpy.try_shutdown()
        except Exception:  # destroy racing a second signal's watchdog exit
            pass
    if status:
        raise SystemExit(status)


def _schedule(nodes: Sequence[Node], name: str) -> None:
    """SCHED_FIFO for the process at the highest `thread_priority` of its nodes (ciml_learning.ros.realtime)."""
    priority = max((int(n.get_parameter(realtime.THREAD_PRIORITY).value) for n in nodes
                    if n.has_parameter(realtime.THREAD_PRIORITY)), default=0)
    if priority <= 0:
        return
    logger = rclpy.logging.get_logger(name if len(nodes) > 1 else nodes[0].get_name())
    failed = realtime.set_fifo_priority(priority)
    if failed:
        logger.warning(f"{failed}: normal scheduling (thread_priority); grant rtprio (docs/LIVE_GRAPH.md) or set 0")
    else:
        logger.info(f"real-time scheduling: SCHED_FIFO priority {priority} (thread_priority)")


def declare(node: Node, name: str, default, description: str, lo: float | None = None, hi: float | None = None,
            read_only: bool = False):
    """Declare one parameter with a description and (for numbers) a range; return its value.

    Prefer `declare_schema` (one schema per node, ciml_learning.core.params)."""
    desc = ParameterDescriptor(description=description, read_only=read_only)
    if lo is not None and hi is not None:
        if isinstance(default, bool):
            pass
        elif isinstance(default, int):
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        elif isinstance(default, float):
            desc.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    return node.declare_parameter(name, default, desc).value


def declare_schema(node: Node, schema: NodeSchema,
                   apply: Callable[[dict[str, Any]], str | None] | None = None) -> dict[str, Any]:
    """Declare every parameter of `schema` (a ciml_learning.core.params.NodeSchema) on `node`, with its
    description, range and read_only flag, and check the start values against the schema
    (choices included); return {name: value}.

    Run-time sets: rclpy refuses read-only parameters and values outside a range itself; the
    other parameters are checked against the schema and then handed to `apply({name: value})`,
    which makes them take effect (and may refuse with a reason string). A schema with
    reconfigurable parameters must come with `apply`: a set is never "successful and ignored".
    """
    from rclpy.exceptions import InvalidParameterValueException

    values: dict[str, Any] = {}
    for p in schema.params:
        desc = ParameterDescriptor(description=p.description_line(), read_only=p.read_only,
                                   additional_constraints=p.constraints_line())
        if p.lo is not None and p.hi is not None and not isinstance(p.default, bool):
            if isinstance(p.default, int):
                desc.integer_range = [IntegerRange(from_value=int(p.lo), to_value=int(p.hi), step=1)]
            elif isinstance(p.default, float):
                desc.floating_point_range = [FloatingPointRange(from_value=float(p.lo), to_value=float(p.hi),
                                                                step=0.0)]
        value = node.declare_parameter(p.name, p.default, desc).value
        problem = p.check(value)
        if problem:
            raise InvalidParameterValueException(p.name, value, problem)
        values[p.name] = value
    if any(not p.read_only for p in schema.params):
        if apply is None:
            raise TypeError(f"{schema.node}: reconfigurable parameters need an apply callback")

        def on_set(params) -> SetParametersResult:
            changes = {}
            for param in params:
                spec = schema.get(param.name)
                if spec is None:  # use_sim_time and other rclpy parameters: rclpy applies them
                    continue
                problem = spec.check(param.value)
                if problem:
                    return SetParametersResult(successful=False, reason=f"{param.name}: {problem}")
                changes[param.name] = param.value
            if changes:
                reason = apply(changes)
                if reason:
                    return SetParametersResult(successful=False, reason=reason)
            return SetParametersResult(successful=True)

        node.add_on_set_parameters_callback(on_set)
    return values


class PublishPeriods:
    """Wall-clock periods between a node's publications on one topic: the rate as the node
    publishes it, before transport and readers add their own delays (a reader on a busy
    machine measures its own scheduling too). Every `window` publications (10 s at 250 Hz) the node's
    /diagnostics counters `<key>_rate_hz` and `<key>_jitter_p99_ms` (p99 of |period − 1/nominal_hz|)
    are updated."""

    def __init__(self, health: Health, key: str, nominal_hz: float, window: int = 2500) -> None:
        self.health, self.key, self.nominal, self.window = health, key, 1.0 / nominal_hz, window
        self._times: list[float] = []

    def mark(self) -> None:
        self._times.append(time.monotonic())
        if len(self._times) > self.window:
            dt = np.diff(self._times)
            self.health.counts[f"{self.key}_rate_hz"] = round(len(dt) / (self._times[-1] - self._times[0]), 1)
            jitter = float(np.percentile(np.abs(dt - self.nominal), 99))
            self.health.counts[f"{self.key}_jitter_p99_ms"] = round(1e3 * jitter, 3)
            self._times = self._times[-1:]


class Health:
    """The node's health on /diagnostics at 1 Hz, the first as soon as the node spins: a level
    and a message that describe the *current* conditions, and event counts as KeyValues.

    - `set(level, message)`: the node's mode ("torque control", "holding the standing pose: …").
    - `condition(key, active, level, message)`: a named condition, raised while `active`, gone
      when cleared.
    - `count(event, warn)`: count an event; with `warn`, the event is also a WARN condition that
      clears `event_hold` seconds after its last occurrence (a rejected message is news for a
      moment, not for the rest of the run; one publish period plus a margin, so every warned
      event reaches at least one /diagnostics message).

    The published level is the worst of the mode and the active conditions; the message is the
    text of those at that level. With nothing active it is the mode's ("ok" by default).
    """

    def __init__(self, node: Node, hardware_id: str = "", event_hold: float = PUBLISH_PERIOD + 0.2) -> None:
        self.node = node
        # a Counter (an event not yet seen reads 0) that also holds measurements (rates, lags: floats),
        # which Counter's type, int values only, does not allow
        self.counts = cast("dict[str, float]", Counter())
        self.mode_level = OK
        self.mode_message = "ok"
        self.event_hold = event_hold
        self._conditions: dict[str, tuple[int, str, float | None]] = {}  # key -> (level, message, last event or None)
        self._hardware_id = hardware_id
        self._pub = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        node.create_timer(PUBLISH_PERIOD, self.publish)
        # the first status at the first spin, not a period later: a monitor (or a launch test)
        # sees the node up as soon as its constructor has finished
        self._first = node.create_timer(FIRST_PUBLISH_DELAY, self._publish_first)

    def _publish_first(self) -> None:
        self._first.cancel()  # cancelled, not destroyed: a callback does not destroy its own timer
        self.publish()

    def count(self, event: str, warn: str | None = None, level: int = WARN) -> None:
        """Count one event; with `warn`, also log it (throttled) and hold it as a condition."""
        self.counts[event] += 1
        if warn is not None:
            self._conditions[event] = (level, warn, time.monotonic())
            self.node.get_logger().warning(f"{warn} ({event}: {self.counts[event]})", throttle_duration_sec=1.0)

    def condition(self, key: str, active: bool, level: int = WARN, message: str = "") -> None:
        """Raise (active) or clear a named condition."""
        if active:
            self._conditions[key] = (level, message or key, None)
        else:
            self._conditions.pop(key, None)

    def set(self, level: int, message: str) -> None:
        """The node's mode (kept until the next set)."""
        self.mode_level, self.mode_message = level, message

    def active(self) -> dict[str, tuple[int, str]]:
        """Conditions active now: key -> (level, message)."""
        now = time.monotonic()
        for key in [k for k, (_, _, t) in self._conditions.items() if t is not None and now - t >= self.event_hold]:
            del self._conditions[key]
        return {k: (lv, m) for k, (lv, m, _) in self._conditions.items()}

    @property
    def level(self) -> int:
        return max([self.mode_level, *(lv for lv, _ in self.active().values())])

    @property
    def message(self) -> str:
        level = self.level
        texts = [self.mode_message] if self.mode_level == level else []
        texts += [m for lv, m in self.active().values() if lv == level]
        return "; ".join(texts)

    def status(self) -> DiagnosticStatus:
        return DiagnosticStatus(
            level=bytes([self.level]),
            name=self.node.get_fully_qualified_name(),
            message=self.message,
            hardware_id=self._hardware_id,
            values=[KeyValue(key=k, value=str(v)) for k, v in sorted(self.counts.items())],
        )

    def publish(self) -> None:
        msg = DiagnosticArray(status=[self.status()])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._pub.publish(msg)
