"""`state_filter`: raw sensor topics → /filtered_state (paper §III-C, online filter).

Thin adapter around ciml_learning.filters.OnlineStateFilter. Each /joint_states sample
is paired by ciml_learning.pairing's rule, as a log is read offline: the latest base state
and contact state at or before it and the latest command strictly before it (the one the
measured torque was produced under), at most max(max_age, 2.5 of that topic's periods) old;
stale partners, wrong joint names, non-finite values and out-of-order stamps are rejected
and counted on /diagnostics. Output is aligned to the filter's delay (≈ 60 ms at any rate).

The filters are designed for the rate of /joint_states: the `rate` parameter, or (0, the
default) the rate measured from the first RATE_SAMPLES stamps (median period, as the
offline pipeline measures a whole log); those first samples are held and filtered once
the rate is known, so nothing is lost and online still equals offline.
"""
from __future__ import annotations

from collections import deque

import numpy as np
from ciml_msgs.msg import ContactState, RobotState, TorqueCommand
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import JointState

from .. import conversions as cv
from .. import topics
from ..errors import CimlError
from ..filters import OnlineStateFilter
from ..node_params import STATE_FILTER
from ..pairing import is_strict, partner
from ..profile import load_profile
from ..ros_common import SENSOR_STREAM_QOS, STREAM_QOS, Health, PublishPeriods, declare_schema, run_node
from ..stamps import measure_rate

RATE_SAMPLES = 32
"""Joint samples whose stamps set the filter's rate when the `rate` parameter is 0."""


class StateFilterNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("state_filter", **kwargs)
        p = declare_schema(self, STATE_FILTER, self._apply_parameters)  # node_params.py: the one schema
        fs, self.max_age = p["rate"], p["max_age"]
        self.robot = load_profile(p["robot"]).robot()
        if 0.0 < fs < 50.0:
            raise CimlError(f"rate {fs} Hz is too low for the 10 Hz low-pass (20 Hz stopband); give ≥ 50 Hz or 0")
        self.filter = OnlineStateFilter(fs) if fs > 0 else None
        self.periods: PublishPeriods | None = None  # /filtered_state as published, once the rate is known
        self._rate_samples: list = []  # held while the rate is measured
        self.health = Health(self)
        self.base: deque = deque(maxlen=16)
        self.contacts: deque = deque(maxlen=16)
        self.commands: deque = deque(maxlen=16)
        self.pending: deque = deque(maxlen=64)
        self.last_stamp = -1
        self.pub = self.create_publisher(RobotState, topics.FILTERED_STATE, STREAM_QOS)
        self.create_subscription(JointState, topics.JOINT_STATES, self.on_joints, SENSOR_STREAM_QOS)
        self.create_subscription(Odometry, topics.BASE_STATE, self.on_base, SENSOR_STREAM_QOS)
        self.create_subscription(ContactState, topics.CONTACT_STATE, self.on_contacts, SENSOR_STREAM_QOS)
        self.create_subscription(TorqueCommand, topics.TORQUE_COMMAND, self.on_command, STREAM_QOS)

    def _apply_parameters(self, changes: dict) -> str | None:
        self.max_age = changes.get("max_age", self.max_age)  # used by the next pairing
        return None

    def _convert(self, what: str, fn, msg):
        try:
            return fn(msg)
        except CimlError as err:
            self.health.count(f"rejected_{what}", f"{what} rejected: {err}")
            return None

    def _store(self, history: deque, msg, value) -> None:
        if value is not None:
            history.append((cv.stamp_to_ns(msg.header.stamp), value))
            self.drain()

    def on_base(self, msg) -> None:
        self._store(self.base, msg, self._convert("base_state", cv.odometry_arrays, msg))

    def on_contacts(self, msg) -> None:
        self._store(self.contacts, msg,
                    self._convert("contact_state", lambda m: cv.contact_state_arrays(self.robot, m), msg))

    def on_command(self, msg) -> None:
        self._store(self.commands, msg,
                    self._convert("torque_command", lambda m: cv.torque_command_arrays(self.robot, m), msg))

    def on_joints(self, msg) -> None:
        stamp = cv.stamp_to_ns(msg.header.stamp)
        newest = self.pending[-1][0] if self.pending else self.last_stamp
        if stamp <= newest:
            self.health.count("out_of_order_stamps", "joint_states stamp did not increase")
            return
        self._store(self.pending, msg,
                    self._convert("joint_states", lambda m: cv.joint_state_arrays(self.robot, m), msg))

    def drain(self) -> None:
        """Process joint samples in stamp order once their partners are final.

        Topics are not ordered relative to each other over DDS, so a joint sample waits
        until a base state, a contact state and a command stamped at or after it have
        arrived (then the command in force before it is known), or until it is older
        than max_age behind the newest joint sample (then it is dropped as stale).
        """
        max_age = int(self.max_age * 1e9)
        while self.pending:
            stamp, joints = self.pending[0]
            complete = all(h and h[-1][0] >= stamp for h in (self.base, self.contacts, self.commands))
            if not complete:
                if self.pending[-1][0] - stamp <= max_age:
                    return
                self.pending.popleft()
                self.health.count("stale_or_missing_partner", "no fresh base state, contact state or command")
                continue
            self.pending.popleft()
            base, contacts, command = (partner(history, stamp, self.max_age, is_strict(role)) for role, history in (
                ("base", self.base), ("contacts", self.contacts), ("command", self.commands)))
            if any(p is None for p in (base, contacts, command)):
                self.health.count("stale_or_missing_partner", "no fresh base state, contact state or command")
                continue
            self.process(stamp, joints, base[1], contacts[1], command[1], command[0])

    def process(self, stamp: int, joints, base, contacts, command, command_stamp: int | None = None) -> None:
        """Filter one sample; u is the joint loop's torque at `stamp` under `command`, stamped
        `command_stamp` [ns] (None: the same instant; TorqueCommand.msg)."""
        self.last_stamp = stamp
        qj, qdj, tau = joints
        pos, quat, twist = base
        q = np.concatenate([pos, quat, qj])
        v = np.concatenate([twist, qdj])
        elapsed = 0.0 if command_stamp is None else (stamp - command_stamp) * 1e-9
        u = command.total(qj, qdj, self.robot.torque_limits, elapsed=elapsed)
        if self.filter is None:
            self._rate_samples.append((stamp * 1e-9, q, v, tau, u, contacts))
            if len(self._rate_samples) < RATE_SAMPLES:
                return
            fs = measure_rate(np.array([x[0] for x in self._rate_samples])).rate_hz
            if not 50.0 <= fs <= 2000.0:
                self.health.count("rate_out_of_range", f"measured /joint_states rate {fs:.1f} Hz is outside 50–2000 Hz")
                self._rate_samples.clear()
                return
            self.get_logger().info(f"/joint_states rate measured from the stamps: {fs:.2f} Hz")
            self.filter = OnlineStateFilter(fs)
            held, self._rate_samples = self._rate_samples, []
        else:
            held = [(stamp * 1e-9, q, v, tau, u, contacts)]
        for sample in held:
            self._filter(*sample)

    def _filter(self, t: float, q, v, tau, u, contacts) -> None:
        try:
            ready = self.filter.push(t, q, v, tau, u, contacts)
        except ValueError as err:
            self.health.count("rejected_samples", str(err))
            return
        if self.periods is None:
            self.periods = PublishPeriods(self.health, "filtered_state", self.filter.fs)
        # joint samples lost upstream: bridged by interpolation, or a restarted warm-up
        self.health.counts["joint_samples_filled"] = self.filter.filled
        self.health.counts["filter_restarts"] = self.filter.restarts
        for out in ready:
            ns = int(round(out.t * 1e9))
            self.pub.publish(cv.robot_state_msg(self.robot, ns, out.q, out.v, out.a, out.tau, out.tau_dot, out.u,
                                                out.contacts, out.valid))
            self.periods.mark()


def main(args=None) -> None:
    run_node(StateFilterNode, args)
