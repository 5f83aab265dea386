"""A robot's own topics, one message at a time, through its profile: the live form of load_log.

The state_filter node subscribes to the topics of the profile's input map (docs/ROBOT_PROFILE.md,
"Live") and hands every message here; LiveInputs reads it with the same per-message readers as
loginputs.load_log reads a bag (JointReader, contact_reader, imu_reading, odometry_reading,
CommandReader), estimates what the profile says to estimate with the estimators' streaming forms
(estimation.Hysteresis, OrientationEstimator, LegOdometry), pairs the roles by the pairing rule
(pairing.partner) and returns each joint sample as the arrays of the online filter
(q, v, τ, u, contacts). A replayed log therefore gives the samples load_log gives, up to messages
lost on the way and the samples before the first stance (load_log back-fills them).

Stamps. A message with a header is placed at its header stamp (unless the profile says
`stamp: log`). A message without one (std_msgs arrays, LowCmd) is placed at the header stamp of
the newest joint state *published* before it, by their publish times (DDS source timestamps):
offline such a message carries its recording time, which falls between the joint states it was
recorded between — the same pairing. With `joint_state.stamp: log` every stamp is a publish time.

Not available live (a one-line error at start): contacts estimated from the legs' dynamics
(its q̈ is a non-causal Savitzky–Golay derivative), per-foot contact topics and a base from two
topics (pose + twist). Pure module: no rclpy.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ciml_learning.core.errors import CimlError
from ciml_learning.core.estimation import EstimationError, Hysteresis, LegOdometry, OrientationEstimator
from ciml_learning.core.pairing import add_to_history, is_strict, partner
from ciml_learning.core.profile import CONTACT_STATE, RobotProfile
from ciml_learning.core.robot import RobotDescription
from ciml_learning.logs.bagio import BagError
from ciml_learning.logs.loginputs import (
    CommandReader,
    JointReader,
    contact_reader,
    imu_acceleration,
    imu_reading,
    odometry_reading,
    twist_in_body,
)

PENDING = 256
"""Joint samples waiting for their partners: the IMU's first ATTITUDE_INIT_S (0.1 s) at up to 2 kHz."""
HISTORY = PENDING
"""Messages kept per role for pairing: as many as joint samples may wait (and ≥ 2.5 periods of a
topic slower than the joint states)."""

SILENT_AFTER = 2.0
"""[s] an input topic without a message this long is silent (≥ 10 periods of a topic at 5 Hz)."""

Reject = Callable[[str, "str | None"], None]
"""on_reject(event, reason): a dropped message or sample, for the node's /diagnostics (reason None:
an expected start-up drop, counted only)."""


class LiveInputError(CimlError):
    """The profile asks for something the live graph cannot read."""


def input_silence(last_heard: Mapping[str, float | None], started: float, now: float,
                  after: float = SILENT_AFTER) -> list[tuple[str, bool, str]]:
    """The silence warnings of the inputs at `now`, as (condition, active, message); times [s] on one
    monotonic clock, `last_heard[topic]` None before its first message, `started` when listening began.

    One topic silent while another speaks (a driver that lost one sensor), or every input silent
    once any was heard (a driver that stopped): both WARN, as a stopped stream must not read as a
    quiet OK. Before the first message nothing is silent: the node waits (its own OK condition)."""
    heard = [t for t in last_heard.values() if t is not None]
    speaking = any(now - t < after for t in heard)
    warnings = []
    for topic, last in last_heard.items():
        quiet = now - (last if last is not None else started)
        warnings.append((f"silent {topic}", speaking and quiet >= after,
                         f"no message on {topic} for {quiet:.1f} s while the other inputs speak"))
    quiet = now - max(heard) if heard else 0.0
    warnings.append(("inputs silent", bool(heard) and not speaking,
                     f"no message on any input for {quiet:.1f} s ({', '.join(last_heard)})"))
    return warnings


class LiveInputs:
    """The profile's roles, live. subscriptions() says what to subscribe to; add(topic, msg,
    publish_ns) takes each message and returns the joint samples now complete, in stamp order:
    (stamp [ns], q (nq), v (nv), τ, u, contacts) as load_log builds them."""

    def __init__(self, robot: RobotDescription, profile: RobotProfile, max_age_s: float,
                 on_reject: Reject | None = None) -> None:
        self.robot, self.profile, self.max_age_s = robot, profile, max_age_s
        self.on_reject: Reject = on_reject or (lambda event, reason: None)
        inputs = profile.inputs
        js, self.base_spec, self.con_spec = inputs["joint_state"], inputs["base"], inputs["contacts"]
        self.imu_spec, cmd_spec = inputs.get("imu"), inputs.get("command")
        if "estimate" in self.con_spec:
            raise LiveInputError("contacts: estimate: dynamics is not available live (its q̈ is a non-causal "
                                 "derivative); give a contact topic (inputs.contacts.topic)")
        if "topics" in self.con_spec:
            raise LiveInputError("contacts: per-foot topics are not available live; give one contact topic")
        if "pose_topic" in self.base_spec:
            raise LiveInputError("base: pose_topic + twist_topic is not available live; give an Odometry topic "
                                 "or estimate: imu_legs")
        self.joint_topic, self.joint_stamp = js["topic"], js["stamp"]
        self.joints = JointReader(robot, profile, js["topic"], need_effort=profile.torque_source != "none")
        # topic -> [(role, stamp source)]: the contacts may be entries of the joint-state messages
        self.roles: dict[str, list[tuple[str, str]]] = {}
        self.types: dict[str, str] = {}

        def add_role(role: str, spec: dict, type_key: str = "type") -> None:
            topic = spec["topic"]
            if topic in self.roles and role == "command":
                raise LiveInputError(f"command: topic {topic} is already the {self.roles[topic][0][0]} input")
            self.roles.setdefault(topic, []).append((role, spec["stamp"]))
            self.types[topic] = spec[type_key]
        add_role("joint_state", js)
        add_role("contacts", self.con_spec)
        self.contacts = contact_reader(robot, self.con_spec)
        self.hysteresis = (Hysteresis(self.con_spec["threshold"], self.con_spec.get("hysteresis", 0.0), robot.n_feet)
                           if "threshold" in self.con_spec else None)
        if self.imu_spec is not None:
            add_role("imu", self.imu_spec)
        self.estimate_orientation = self.imu_spec is not None and self.imu_spec.get("orientation") == "estimate"
        self.orientation = OrientationEstimator()
        self._imu_held: deque[tuple[int, np.ndarray]] = deque()  # (stamp, gyro) held by the estimator
        if "topic" in self.base_spec:
            add_role("base", self.base_spec)
            self.legs = None
        else:  # estimate: imu_legs (the profile requires inputs.imu for it)
            self.legs = LegOdometry(robot, self.imu_spec.get("frame") if self.imu_spec else None)
        self.command = CommandReader(robot, profile, cmd_spec) if cmd_spec is not None else None
        if cmd_spec is not None:
            add_role("command", cmd_spec)
        self.history: dict[str, deque] = {role: deque(maxlen=HISTORY) for role in ("contacts", "imu", "base",
                                                                                   "command")}
        self.measured = ["contacts"] + (["imu"] if self.imu_spec is not None else []) + (
            ["base"] if self.legs is None else []) + (["command"] if self.command is not None else [])
        self.pending: deque[tuple[int, tuple]] = deque(maxlen=PENDING)
        self._joint_clock: deque[tuple[int, int]] = deque(maxlen=HISTORY)  # (publish ns, joint stamp ns)
        self.newest_joint = -1

    def subscriptions(self) -> list[tuple[str, str, list[str]]]:
        """(topic, message type, roles) to subscribe to, the joint-state topic first."""
        return [(t, self.types[t], [r for r, _ in roles]) for t, roles in self.roles.items()]

    # --- one message --------------------------------------------------------------------------
    def add(self, topic: str, msg: Any, publish_ns: int) -> list[tuple]:
        """Read one message of `topic` (publish_ns: its publish time) → the joint samples completed."""
        for role, source in self.roles.get(topic, ()):
            stamp = self._stamp(role, source, msg, publish_ns)
            if stamp is None:
                self.on_reject(f"rejected_{role}", f"{role} ({topic}): published before any joint state")
                continue
            if role == "joint_state":
                self._joint_clock.append((int(publish_ns), stamp))
            try:
                getattr(self, f"_on_{role}")(stamp, msg)
            except (ValueError, BagError, EstimationError, CimlError) as err:
                self.on_reject(f"rejected_{role}", f"{role} ({topic}) rejected: {err}")
        return self._drain()

    def _stamp(self, role: str, source: str, msg: Any, publish_ns: int) -> int | None:
        header = getattr(msg, "header", None)
        if source == "header" and header is not None:
            return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        if role == "joint_state" or self.joint_stamp == "log":
            return int(publish_ns)
        # headerless: the stamp of the newest joint state published before it (module docstring)
        before = [stamp for pub, stamp in self._joint_clock if pub <= publish_ns]
        return before[-1] if before else None

    def _on_joint_state(self, stamp: int, msg: Any) -> None:
        if stamp <= self.newest_joint:
            self.on_reject("out_of_order_stamps", "joint_states stamp did not increase")
            return
        joints = self.joints(msg)
        self.newest_joint = stamp
        self.pending.append((stamp, joints))

    def _on_contacts(self, stamp: int, msg: Any) -> None:
        values = self.contacts(msg)
        if self.con_spec["type"] == CONTACT_STATE:
            flags = values
        elif not np.all(np.isfinite(values)):
            raise ValueError(f"field {self.con_spec.get('field')}: non-finite value")
        else:
            flags = self.hysteresis.step(values) if self.hysteresis is not None else values != 0
        add_to_history(self.history["contacts"], stamp, np.asarray(flags, dtype=bool))

    def _on_imu(self, stamp: int, msg: Any) -> None:
        quat, gyro, accel = imu_reading(msg)
        if quat is not None and not self.estimate_orientation:
            add_to_history(self.history["imu"], stamp, (quat, gyro))
            return
        # no quaternion (auto: from this message on) or `orientation: estimate`: gyro and accelerometer
        self.estimate_orientation = True
        self._imu_held.append((stamp, gyro))
        try:
            out = self.orientation.push(stamp * 1e-9, gyro, imu_acceleration(accel))
        except ValueError:
            self._imu_held.pop()
            raise
        for _, q in out:
            s, g = self._imu_held.popleft()
            add_to_history(self.history["imu"], s, (q, g))

    def _on_base(self, stamp: int, msg: Any) -> None:
        pos, quat, twist = odometry_reading(msg)
        if self.base_spec["twist_frame"] == "world":
            twist = twist_in_body(quat, twist)
        add_to_history(self.history["base"], stamp, (pos, quat, twist))

    def _on_command(self, stamp: int, msg: Any) -> None:
        assert self.command is not None
        add_to_history(self.history["command"], stamp, self.command.read(msg))

    # --- pairing ------------------------------------------------------------------------------
    def _drain(self) -> list[tuple]:
        """Joint samples in stamp order once their partners are final (a partner stamped at or after
        the sample arrived), or dropped as stale once max_age behind the newest joint sample."""
        out = []
        max_age = int(self.max_age_s * 1e9)
        while self.pending:
            stamp, joints = self.pending[0]
            hist = [self.history[r] for r in self.measured]
            if not all(h and h[-1][0] >= stamp for h in hist):
                # the attitude estimate holds the IMU's first ATTITUDE_INIT_S: so do the joint samples
                initialising = self.estimate_orientation and self.orientation.filter is None
                if initialising or self.pending[-1][0] - stamp <= max_age:
                    break
                self.pending.popleft()
                self.on_reject("stale_or_missing_partner", f"no fresh {', '.join(self._missing(stamp))} message")
                continue
            self.pending.popleft()
            found = {r: partner(self.history[r], stamp, self.max_age_s, is_strict(r)) for r in self.measured}
            missing = [r for r, p in found.items() if p is None]
            if missing:
                self.on_reject("stale_or_missing_partner", f"no fresh {', '.join(missing)} message")
                continue
            sample = self._sample(stamp, joints, found)
            if sample is not None:
                out.append(sample)
        return out

    def _missing(self, stamp: int) -> list[str]:
        return [r for r in self.measured if not (self.history[r] and self.history[r][-1][0] >= stamp)]

    def _sample(self, stamp: int, joints: tuple, found: dict) -> tuple | None:
        qj, qdj, tau = joints
        contacts = found["contacts"][1]
        if self.legs is None:
            pos, quat, twist = found["base"][1]
        else:
            quat_imu, gyro = found["imu"][1]
            base = self.legs.step(stamp * 1e-9, qj, qdj, quat_imu, gyro, contacts)
            if base is None:
                self.on_reject("before_first_stance", None)  # a stream cannot back-fill as load_log does
                return None
            pos, quat, twist = base
        u = tau
        if self.command is not None:
            cstamp, row = found["command"]
            u = self.command.u(row, qj, qdj, (stamp - cstamp) * 1e-9)
        if self.profile.torque_source == "none":
            tau = u  # the command is the only torque (load_log does the same)
        return stamp, np.concatenate([pos, quat, qj]), np.concatenate([twist, qdj]), tau, u, contacts
