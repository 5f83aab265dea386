"""Reading a robot's own log through its profile: roles, topics, types, field paths.

Every role of the profile (docs/ROBOT_PROFILE.md) is read from its topic — or estimated —
into a bagio.SensorLog at the joint-state stamps, in the URDF's joint and foot orders:

- joint_state: sensor_msgs/JointState; names renamed by joint_map; entries that are not
  URDF joints (foot sensors, grippers) are ignored and listed; missing joints are an error.
- base: nav_msgs/Odometry (twist in the child/body frame, REP 105, or in the world frame and
  rotated here), pose + twist topics, or estimated from the IMU and the stance legs
  (estimation.estimate_base).
- contacts: ciml_msgs/ContactState; per-foot values from any message by field path
  (booleans, or forces/pressures with a threshold and hysteresis: estimation.threshold_contacts);
  per-foot topics (WrenchStamped); or estimated from the legs' dynamics (estimation.estimate_contacts).
- command: ciml_msgs/TorqueCommand (the joint loop's law, TorqueCommand.msg), effort arrays
  (Float64MultiArray + joint list, or JointState effort), a low-level PD command by field
  paths (u = τ_ff + k_p (q_des − q) + k_d (q̇_des − q̇)), or none: u is set to τ so that
  Γ = τ − u (eq. 14) is zero, `u_observed` is False and a warning says the actuation error
  is not observable.

Bags are read with rosbags' AnyReader: rosbag2 MCAP and sqlite3 (db3), ROS 1 .bag; message
types come from the bag's own embedded definitions, so types CIML does not know (a Unitree
LowCmd) are readable by field path. The rate is measured from the joint-state stamps
(stamps.measure_rate) and the stamp problems are reported. Every rejection names the role,
its topic, the field and why, in one line. Each role's message is read by one per-message
reader (JointReader, contact_reader, imu_reading, odometry_reading, CommandReader), which the
live graph's state_filter calls too (live_inputs). Pure module: no rclpy.
"""
from __future__ import annotations

import array
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ciml_learning.core.filters import derivative_taps, filter_offline
from ciml_learning.core.pairing import age_limit_ns, is_strict, partner_indices
from ciml_learning.core.profile import CONTACT_STATE, JOINT_STATE, ODOMETRY, TORQUE_COMMAND, RobotProfile, load_profile
from ciml_learning.core.robot import RobotDescription
from ciml_learning.core.stamps import count_zero_stamps, measure_rate
from ciml_learning.logs.bagio import BagError, SensorLog, open_reader

TORQUE_FOLLOWS_COMMAND_R = 0.998
"""Median per-joint correlation of measured torque and command above which Γ = τ − u is
reported not observable (the "measured" torque is the command, e.g. a current estimate).
Measured on CIML's simulated HyQ logs: with real actuator effects (default gap: lag,
friction, a weak actuator) the median is 0.9967 (per joint 0.992–0.998); without any
actuator effect it is 1.0 — the warning then says Γ is zero or not observable."""


# --- field paths ----------------------------------------------------------------------

_TOKEN = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[(?:\d+|\*)\])*)")


def parse_field_path(path: str) -> list[tuple[str, list[str]]]:
    """'motor_cmd[*].q' → [('motor_cmd', ['*']), ('q', [])]; raises ValueError on bad syntax."""
    out = []
    for part in path.split("."):
        m = _TOKEN.fullmatch(part)
        if not m:
            raise ValueError(f"bad field path {path!r} at {part!r} (use a.b[2].c or a[*].b)")
        out.append((m.group(1), re.findall(r"\[(\d+|\*)\]", m.group(2))))
    return out


def field_values(msg: Any, path: str | list) -> np.ndarray:
    """Values of a field path in a message as a float array ([*] gives one value per element).

    Raises ValueError naming the missing attribute or index.
    """
    steps = parse_field_path(path) if isinstance(path, str) else path
    items = [msg]
    for name, indices in steps:
        nxt = []
        for it in items:
            if not hasattr(it, name):
                fields = list(getattr(it, "__dataclass_fields__", {})) or [a for a in dir(it) if not a.startswith("_")]
                raise ValueError(f"no field {name!r} (fields: {', '.join(fields)})")
            nxt.append(getattr(it, name))
        items = nxt
        for idx in indices:
            nxt = []
            for it in items:
                seq = list(it) if not isinstance(it, np.ndarray) else it
                if idx == "*":
                    nxt.extend(seq)
                else:
                    k = int(idx)
                    if k >= len(seq):
                        raise ValueError(f"index [{k}] of {name!r} out of range (length {len(seq)})")
                    nxt.append(seq[k])
            items = nxt
    flat: list[float] = []
    for it in items:
        if isinstance(it, (np.ndarray, list, tuple, array.array)):  # rclpy holds numeric arrays as array.array
            flat.extend(np.asarray(it, dtype=float).ravel().tolist())
        else:
            flat.append(float(it))
    return np.asarray(flat, dtype=float)


# --- reading topics -------------------------------------------------------------------


class _Topic:
    """Messages of one topic, sorted by stamp: stamps [ns], messages, stamp report."""

    def __init__(self, role: str, topic: str, stamps: np.ndarray, msgs: list, report: dict) -> None:
        self.role, self.topic, self.t, self.msgs, self.report = role, topic, stamps, msgs, report

    def __len__(self) -> int:
        return len(self.t)


def message_stamp_ns(msg, log_ns: int, source: str) -> int:
    if source == "log":
        return log_ns
    header = getattr(msg, "header", None)
    if header is None:
        return log_ns  # headerless types (std_msgs arrays) carry only the recording time
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def read_topics(path: str | os.PathLike, wanted: dict[str, tuple[str, str, str]],
                rej: "_Rejections | None" = None) -> dict[str, _Topic]:
    """Read the wanted topics of one bag (topic → (role, expected type, stamp source)).

    Missing topics, wrong types and all-zero stamps are one-line BagErrors naming the role.
    """
    from rosbags.highlevel import AnyReaderError

    rej = rej if rej is not None else _Rejections()
    reader = open_reader([path])
    raw: dict[str, list] = {t: [] for t in wanted}
    try:
        bag_types = {c.topic: c.msgtype for c in reader.connections}
        for topic, (role, typ, _) in wanted.items():
            if topic not in bag_types:
                avail = ", ".join(f"{t} ({y})" for t, y in sorted(bag_types.items()))
                hint = (" — remove inputs.command from the profile if the robot logs no command"
                        if role == "command" else "")
                raise BagError(f"{role}: bag {path} has no messages on {topic} ({typ}); topics in the bag: "
                               f"{avail}{hint}")
            if typ and bag_types[topic] != typ:
                raise BagError(f"{role}: {topic} in bag {path} is {bag_types[topic]}, the profile says {typ}")
        conns = [c for c in reader.connections if c.topic in wanted]
        for conn, log_ns, data in reader.messages(connections=conns):
            msg = reader.deserialize(data, conn.msgtype)
            raw[conn.topic].append((message_stamp_ns(msg, log_ns, wanted[conn.topic][2]), msg))
    except (AnyReaderError, EOFError, ValueError, KeyError) as err:
        raise BagError(f"bag {path} is truncated or corrupt ({type(err).__name__}: {err}); "
                         "try 'mcap recover' (MCAP) or 'ros2 bag reindex' (db3)") from err
    finally:
        reader.close()
    out = {}
    for topic, items in raw.items():
        role, typ, source = wanted[topic]
        if not items:
            raise BagError(f"{role}: bag {path} has no messages on {topic}")
        stamps = np.array([s for s, _ in items], dtype=np.int64)
        report = measure_rate(stamps * 1e-9).as_dict()
        nonzero = stamps != 0
        if count_zero_stamps(stamps) == 0:
            nonzero[:] = True  # a lone first stamp at 0 is a clock that starts there
        if not nonzero.any() or (len(stamps) > 1 and nonzero.sum() <= 1):
            raise BagError(f"{role}: header.stamp is zero in all {len(stamps)} messages on {topic}; "
                           f"set inputs.{role}.stamp: log to use the recording time")
        order = np.argsort(stamps, kind="stable")  # equal stamps keep bag order
        order = order[nonzero[order]]
        if (~nonzero).any():
            rej.add(role, topic, "header.stamp is zero", int((~nonzero).sum()))
        out[topic] = _Topic(role, topic, stamps[order], [items[i][1] for i in order], report)
    return out


class _Rejections:
    """Per role: counts of rejected messages by reason, and the first reason (for errors)."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}

    def add(self, role: str, topic: str, reason: str, count: int = 1) -> None:
        key = f"{role} ({topic}): {reason}"
        self.counts[key] = self.counts.get(key, 0) + count

    def first(self, role: str) -> str:
        keys = [k for k in self.counts if k.startswith(f"{role} (")]
        return max(keys, key=lambda k: self.counts[k]) if keys else f"{role}: no usable message"


def _convert(top: _Topic, rej: _Rejections, fn) -> tuple[np.ndarray, list]:
    """Apply fn to every message; ValueErrors reject the message with their reason."""
    keep_t, rows = [], []
    for stamp, msg in zip(top.t, top.msgs):
        try:
            rows.append(fn(msg))
            keep_t.append(stamp)
        except ValueError as err:
            rej.add(top.role, top.topic, str(err))
    if not rows:
        raise BagError(f"all {len(top)} messages rejected — {rej.first(top.role)}")
    return np.asarray(keep_t, dtype=np.int64), rows


def _finite(what: str, *arrays: np.ndarray) -> None:
    for a in arrays:
        if a.size and not np.all(np.isfinite(a)):
            raise ValueError(f"{what}: non-finite value")


def _quat(o, what: str) -> np.ndarray:
    q = np.array([o.x, o.y, o.z, o.w], dtype=float)
    _finite(what, q)
    n = np.linalg.norm(q)
    if n < 1e-6:
        raise ValueError(f"{what} is a zero quaternion")
    if not 0.9 < n < 1.1:
        raise ValueError(f"{what} has norm {n:.3f}, expected 1")
    return q / n


def _rotate_to_body(quat_xyzw: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """Rᵀ v: a world-frame vector in the body frame of orientation quat (x, y, z, w)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(quat_xyzw).inv().apply(vec)


# --- roles ----------------------------------------------------------------------------


class JointReader:
    """sensor_msgs/JointState → (q, q̇, τ) in URDF order, by name through joint_map (a bag's or a
    live topic's message)."""

    def __init__(self, robot: RobotDescription, profile: RobotProfile, topic: str, need_effort: bool) -> None:
        self.robot, self.profile, self.topic, self.need_effort = robot, profile, topic, need_effort
        self._perm: dict[tuple, np.ndarray] = {}
        self.extra: set[str] = set()

    def perm(self, names: Sequence[str]) -> np.ndarray:
        key = tuple(names)
        p = self._perm.get(key)
        if p is None:
            mapped = [self.profile.to_urdf_name(n) for n in names]
            index = {n: i for i, n in enumerate(mapped)}
            missing = [j for j in self.robot.joint_names if j not in index]
            if missing:
                raise BagError(
                    f"joint_state ({self.topic}): joints {missing} of the URDF are missing from name[] "
                    f"(the message names {list(names)}); map them with joint_map")
            if len(set(mapped)) != len(mapped):
                raise BagError(f"joint_state ({self.topic}): name[] repeats a joint: {list(names)}")
            self.extra |= {n for n, m in zip(names, mapped) if m not in self.robot.joint_names}
            p = np.array([index[j] for j in self.robot.joint_names], dtype=int)
            self._perm[key] = p
        return p

    def __call__(self, msg) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p = self.perm(list(msg.name))
        n = len(msg.name)
        pos, vel, eff = (np.asarray(x, dtype=float) for x in (msg.position, msg.velocity, msg.effort))
        if pos.size != n or vel.size != n:
            raise ValueError(f"position/velocity have {pos.size}/{vel.size} values for {n} names")
        if eff.size != n:
            if self.need_effort or eff.size:
                raise ValueError(f"effort has {eff.size} values for {n} names")
            eff = np.full(n, np.nan)
        q, qd, tau = pos[p], vel[p], eff[p]
        _finite("position/velocity/effort", q, qd, tau if self.need_effort else q)
        return q, qd, tau


def _foot_order(robot: RobotDescription, names: Sequence[str] | None, n_values: int) -> np.ndarray:
    if names is None:
        if n_values != robot.n_feet:
            raise ValueError(f"{n_values} values for {robot.n_feet} feet (give `order:` or `names:`)")
        return np.arange(robot.n_feet)
    return robot.foot_permutation(list(names))


def _threshold(force: np.ndarray, spec: dict) -> np.ndarray:
    from ciml_learning.core.estimation import threshold_contacts

    return np.asarray(threshold_contacts(force, spec["threshold"], spec.get("hysteresis", 0.0)), dtype=bool)


def _read_contacts(robot, spec, tops, rej, joint_top) -> tuple[np.ndarray, np.ndarray, str]:
    """(stamps [ns], contacts (M × n_feet) bool, source description) of a measured contact input."""
    if "topics" in spec:
        per_foot = {robot.foot_frames[i]: i for i in range(robot.n_feet)}
        unknown = [f for f in spec["topics"] if f not in per_foot]
        missing = [f for f in robot.foot_frames if f not in spec["topics"]]
        if unknown or missing:
            raise BagError(f"contacts: topics must name every foot frame once: missing {missing}, unknown {unknown}")
        series = []
        for foot in robot.foot_frames:
            top = tops[spec["topics"][foot]]
            t, rows = _convert(top, rej, lambda m: _scalar(field_values(m, spec["field"]), spec["field"]))
            series.append((t, np.asarray(rows)))
        t = np.unique(np.concatenate([s[0] for s in series]))
        vals = np.full((len(t), robot.n_feet), np.nan)
        for k, (ts, x) in enumerate(series):
            idx = np.searchsorted(ts, t, side="right") - 1
            ok = idx >= 0
            vals[ok, k] = x[idx[ok]]
        keep = np.all(np.isfinite(vals), axis=1)
        t, vals = t[keep], vals[keep]
        desc = f"per-foot topics {spec['topics']} ({spec['type']}, field {spec['field']})"
    else:
        top = tops[spec["topic"]] if spec["topic"] in tops else joint_top
        read = contact_reader(robot, spec)
        t, rows = _convert(top, rej, read)
        if spec["type"] == CONTACT_STATE:
            return t, np.asarray(rows, dtype=bool), f"topic {top.topic} ({CONTACT_STATE})"
        vals = np.asarray(rows, dtype=float)
        desc = f"topic {top.topic} ({spec['type']}, field {spec.get('field')})"
    finite = np.all(np.isfinite(vals), axis=1)
    t, vals = t[finite], vals[finite]
    if "threshold" in spec:
        return t, _threshold(vals, spec), desc + f", threshold {spec['threshold']:g} ± {spec['hysteresis']:g}"
    return t, vals != 0, desc + " (non-zero = contact)"


def contact_reader(robot: RobotDescription, spec: dict) -> Callable[[Any], np.ndarray]:
    """One message of a single-topic contacts input → per-foot values in the robot's foot order:
    flags (ContactState, by foot name) or the field's values (forces, pressures or flags) — the
    one reading of such a message, for a bag (load_log) and a live topic (live_inputs).
    A message that cannot be read raises ValueError; a ContactState naming other feet, BagError."""
    if spec["type"] == CONTACT_STATE:
        def read_flags(m) -> np.ndarray:
            flags = np.asarray(m.in_contact, dtype=bool)
            if flags.shape != (len(m.foot_names),):
                raise ValueError(f"{len(m.foot_names)} foot_names but {flags.size} in_contact flags")
            try:
                return flags[robot.foot_permutation(list(m.foot_names))]
            except Exception as err:
                raise BagError(f"contacts ({spec['topic']}): {err}") from err
        return read_flags
    if spec["type"] == JOINT_STATE:
        names = list(spec["names"])
        perm = robot.foot_permutation(names)

        def read_entries(m) -> np.ndarray:
            index = {n: i for i, n in enumerate(m.name)}
            missing = [n for n in names if n not in index]
            if missing:
                raise ValueError(f"name[] lacks the foot entries {missing}")
            vals = np.asarray(getattr(m, spec["field"]), dtype=float)
            if vals.size != len(m.name):
                raise ValueError(f"{spec['field']} has {vals.size} values for {len(m.name)} names")
            return vals[[index[n] for n in names]][perm]
        return read_entries

    def read_field(m) -> np.ndarray:
        vals = field_values(m, spec["field"])
        return vals[_foot_order(robot, spec.get("order"), vals.size)]
    return read_field


def _scalar(v: np.ndarray, path: str) -> float:
    if v.size != 1:
        raise ValueError(f"field {path} holds {v.size} values, expected one per foot topic")
    return float(v[0])


def odometry_reading(m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """nav_msgs/Odometry → (position [m], quaternion x y z w, twist [linear, angular] as logged);
    the one reading of a base message, for a bag and a live topic. Raises ValueError."""
    p, tw = m.pose.pose.position, m.twist.twist
    pos = np.array([p.x, p.y, p.z], dtype=float)
    quat = _quat(m.pose.pose.orientation, "pose.pose.orientation")
    twist = np.array([tw.linear.x, tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y, tw.angular.z], dtype=float)
    _finite("pose.pose.position / twist.twist", pos, twist)
    return pos, quat, twist


def twist_in_body(quat_xyzw: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """A world-frame twist ([linear, angular], one or N rows) in the base frame (twist_frame: world)."""
    return np.hstack([_rotate_to_body(quat_xyzw, twist[..., :3]), _rotate_to_body(quat_xyzw, twist[..., 3:])])


def _read_base(spec, tops, rej, warnings: list[str]):
    """(stamps, positions, quaternions, twists in the body frame, description) of a measured base input."""
    if "topic" in spec:
        top = tops[spec["topic"]]
        t, rows = _convert(top, rej, odometry_reading)
        pos = np.array([r[0] for r in rows])
        quat = np.array([r[1] for r in rows])
        twist = np.array([r[2] for r in rows])
        desc = f"topic {top.topic} ({ODOMETRY})"
        frames = {getattr(m, "child_frame_id", "") for m in top.msgs[:50]}
        parents = {m.header.frame_id for m in top.msgs[:50]}
    else:
        ptop, ttop = tops[spec["pose_topic"]], tops[spec["twist_topic"]]

        def pconv(m):
            pose = m.pose.pose if spec["pose_type"] != "geometry_msgs/msg/PoseStamped" else m.pose
            p = pose.position
            pos = np.array([p.x, p.y, p.z], dtype=float)
            _finite("pose.position", pos)
            return pos, _quat(pose.orientation, "pose.orientation")

        def tconv(m):
            tw = m.twist.twist if spec["twist_type"] != "geometry_msgs/msg/TwistStamped" else m.twist
            x = np.array([tw.linear.x, tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y, tw.angular.z])
            _finite("twist", x)
            return x
        t, prow = _convert(ptop, rej, pconv)
        tt, trow = _convert(ttop, rej, tconv)
        idx = partner_indices(tt, t, int(0.05e9))  # a twist at or before each pose
        ok = idx >= 0
        if not ok.any():
            raise BagError(f"base ({ttop.topic}): no twist within 0.05 s of any pose on {ptop.topic}")
        t = t[ok]
        pos = np.array([r[0] for r, k in zip(prow, ok) if k])
        quat = np.array([r[1] for r, k in zip(prow, ok) if k])
        twist = np.asarray(trow)[idx[ok]]
        desc = f"topics {ptop.topic} ({spec['pose_type']}) + {ttop.topic} ({spec['twist_type']})"
        frames = {ttop.msgs[0].header.frame_id} if hasattr(ttop.msgs[0], "header") else set()
        parents = {ptop.msgs[0].header.frame_id} if hasattr(ptop.msgs[0], "header") else set()
    if spec["twist_frame"] == "world":
        twist = twist_in_body(quat, twist)
        desc += ", twist in the world frame rotated into the base frame"
    else:
        desc += f", twist in the base frame (child_frame_id {sorted(frames)})"
        if frames and frames == parents and "" not in frames:
            # the twist's frame is the pose's parent frame: a world-frame twist read as a body one
            warnings.append(f"base: the twist's frame {sorted(frames)} is the pose's frame_id; if the twist is in "
                            "the world frame set inputs.base.twist_frame: world")
    return t, pos, quat, twist, desc


def imu_has_orientation(m) -> bool:
    """Whether a sensor_msgs/Imu carries an orientation: not when its quaternion is zero (drivers
    that never fill it) nor when orientation_covariance[0] is −1 (the message's own "no estimate")."""
    o = m.orientation
    cov = np.asarray(m.orientation_covariance, dtype=float)
    return not (cov.size and cov[0] == -1.0) and bool(np.linalg.norm([o.x, o.y, o.z, o.w]) >= 1e-6)


def _vector3(v, what: str) -> np.ndarray:
    x = np.array([v.x, v.y, v.z], dtype=float)
    _finite(what, x)
    return x


def imu_reading(m) -> tuple[np.ndarray | None, np.ndarray, Any]:
    """sensor_msgs/Imu → (quaternion x y z w, or None when it carries none: imu_has_orientation;
    gyro [rad/s]; the linear_acceleration field, read by imu_acceleration only where the
    orientation is estimated) — the one reading of an IMU message, for a bag and a live topic."""
    q = _quat(m.orientation, "orientation") if imu_has_orientation(m) else None
    return q, _vector3(m.angular_velocity, "angular_velocity"), m.linear_acceleration


def imu_acceleration(field) -> np.ndarray:
    """The IMU's specific force [m/s²] (REP 145) of imu_reading's third value; ValueError if not finite."""
    return _vector3(field, "linear_acceleration")


def _read_imu(spec, tops, rej) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(stamps [ns], orientation (M × 4, x y z w), gyro (M × 3) [rad/s], source description): the
    quaternion as logged, or estimated from gyro and accelerometer (estimation.estimate_orientation)
    when the profile says `orientation: estimate` or, with `auto`, when a message has none."""
    top = tops[spec["topic"]]
    t, rows = _convert(top, rej, imu_reading)
    gyro = np.array([r[1] for r in rows])
    missing = sum(r[0] is None for r in rows)
    desc = f"topic {spec['topic']} (sensor_msgs/msg/Imu)"
    if spec.get("orientation", "auto") != "estimate" and not missing:
        return t, np.array([r[0] for r in rows]), gyro, desc
    from ciml_learning.core.estimation import estimate_orientation

    accel: list[np.ndarray | None] = []
    for r in rows:
        try:
            accel.append(imu_acceleration(r[2]))
        except ValueError as err:
            rej.add(top.role, top.topic, str(err))
            accel.append(None)
    keep = np.array([a is not None for a in accel])
    if not keep.any():
        raise BagError(f"imu ({top.topic}): no message with a finite linear_acceleration to estimate orientation")
    t, gyro = t[keep], gyro[keep]
    quat = estimate_orientation(t * 1e-9, gyro, np.array([a for a in accel if a is not None]))
    why = "the profile says orientation: estimate" if not missing else f"{missing} of {len(rows)} messages carry none"
    return t, quat, gyro, (f"{desc}; orientation estimated from gyro and accelerometer ({why}; Mahony "
                           "complementary filter, estimation.estimate_orientation)")


class CommandReader:
    """The command input's law: read(msg) → a row (one message, as the profile says), and
    u(row, q, q̇, dt) → the torque it asks for at a sample dt seconds after the command, clipped
    to the torque limits — the one reading of a command, for a bag (load_log) and a live topic
    (live_inputs). read raises ValueError for a message it rejects, BagError when the message
    cannot fit the profile (joint names of another robot)."""

    def __init__(self, robot: RobotDescription, profile: RobotProfile, spec: dict) -> None:
        self.robot, self.spec, self.topic = robot, spec, spec["topic"]
        self.read: Callable[[Any], Any]
        self.u: Callable[[Any, np.ndarray, np.ndarray, float], np.ndarray]
        limits = robot.torque_limits
        if spec["type"] == TORQUE_COMMAND:
            from ciml_learning.core.conversions import ConversionError, torque_command_arrays

            def read_torque_command(m):
                try:
                    return torque_command_arrays(robot, m)
                except ConversionError as err:
                    if "do not match the robot" in str(err):
                        raise BagError(f"command ({self.topic}): {err}") from err
                    raise ValueError(str(err)) from err
            self.read = read_torque_command
            self.u = lambda row, q, qd, dt: row.total(q, qd, limits, elapsed=dt)
            self.desc = f"topic {self.topic} ({TORQUE_COMMAND}, the joint loop's law)"
        elif "fields" in spec:
            f = spec["fields"]
            perm = self._perm(profile, spec["joints"])
            n = len(spec["joints"])

            def read_pd(m):
                vals = {}
                for key, path in f.items():
                    v = field_values(m, path)
                    if v.size < n:
                        raise ValueError(f"field {path} has {v.size} values for {n} joints")
                    vals[key] = v[:n][perm]  # arrays may be longer than the robot (LowCmd has 20 motors)
                    _finite(f"field {path}", vals[key])
                return vals
            zero = np.zeros(robot.n_joints)

            def pd(c, q, qd, dt):
                u = c.get("tau_ff", zero)
                if "kp" in c:
                    u = u + c["kp"] * (c["q_des"] - q)
                if "kd" in c:
                    u = u + c["kd"] * (c.get("dq_des", zero) - qd)
                return np.clip(u, -limits, limits)
            self.read, self.u = read_pd, pd
            self.desc = f"topic {self.topic} ({spec['type']}, low-level PD by field paths)"
        else:
            if spec["type"] == JOINT_STATE:
                def read_efforts(m):
                    names = [profile.to_urdf_name(x) for x in m.name]
                    vals = np.asarray(getattr(m, spec["field"]), dtype=float)
                    if vals.size != len(names):
                        raise ValueError(f"{spec['field']} has {vals.size} values for {len(names)} names")
                    index = {x: i for i, x in enumerate(names)}
                    missing = [j for j in robot.joint_names if j not in index]
                    if missing:
                        raise ValueError(f"name[] lacks joints {missing}")
                    out = vals[[index[j] for j in robot.joint_names]]
                    _finite(spec["field"], out)
                    return out
                self.read = read_efforts
            else:
                perm = self._perm(profile, spec["joints"])
                n = len(spec["joints"])

                def read_array(m):
                    v = field_values(m, spec["field"])
                    if v.size != n:
                        raise ValueError(f"field {spec['field']} has {v.size} values for {n} joints")
                    _finite(f"field {spec['field']}", v)
                    return v[perm]
                self.read = read_array
            self.u = lambda row, q, qd, dt: np.clip(row, -limits, limits)
            self.desc = f"topic {self.topic} ({spec['type']}, field {spec['field']}: joint efforts)"

    def _perm(self, profile, joints) -> np.ndarray:
        mapped = [profile.to_urdf_name(j) for j in joints]
        missing = [j for j in self.robot.joint_names if j not in mapped]
        unknown = [j for j in mapped if j not in self.robot.joint_names]
        if missing or unknown:
            raise BagError(f"command ({self.spec['topic']}): joints lists missing {missing}, unknown {unknown}; "
                           f"expected the URDF's {list(self.robot.joint_names)} in the array's order")
        return np.array([mapped.index(j) for j in self.robot.joint_names], dtype=int)


class _Command:
    """A bag's command input: its stamps [ns], rows and u at a sample (CommandReader's law)."""

    def __init__(self, robot, profile, spec, tops, rej) -> None:
        reader = CommandReader(robot, profile, spec)
        self.topic, self.desc = reader.topic, reader.desc
        self.t, self.rows = _convert(tops[spec["topic"]], rej, reader.read)
        self.law = reader.u

    def u(self, i: int, q: np.ndarray, qd: np.ndarray, dt: float) -> np.ndarray:
        return self.law(self.rows[i], q, qd, dt)


@dataclass
class RoleSeries:
    """A measured role's messages in stamp order: stamps [ns], per-message values (arrays of M
    rows), each value's fill for a joint sample without a partner, the topic errors name, and the
    source description."""

    t: np.ndarray
    values: tuple[np.ndarray, ...]
    missing: tuple[Any, ...]
    topic: str
    source: str


_IDENTITY_XYZW = np.array([0.0, 0.0, 0.0, 1.0])


def _contacts_series(robot, spec, tops, rej, warnings, joint_top) -> RoleSeries:
    t, flags, source = _read_contacts(robot, spec, tops, rej, joint_top)
    if len(t) == 0:
        raise BagError(f"contacts: no usable message — {rej.first('contacts')}")
    return RoleSeries(t, (flags,), (False,), spec.get("topic", "per-foot topics"), source)


def _imu_series(robot, spec, tops, rej, warnings, joint_top) -> RoleSeries:
    t, quat, gyro, source = _read_imu(spec, tops, rej)
    return RoleSeries(t, (quat, gyro), (_IDENTITY_XYZW, 0.0), spec["topic"], source)


def _base_series(robot, spec, tops, rej, warnings, joint_top) -> RoleSeries:
    t, pos, quat, twist, source = _read_base(spec, tops, rej, warnings)
    topic = spec["topic"] if "topic" in spec else spec["pose_topic"]
    return RoleSeries(t, (pos, quat, twist), (0.0, _IDENTITY_XYZW, 0.0), topic, source)


MEASURED_ROLES: tuple[tuple[str, Callable[..., RoleSeries]], ...] = (
    ("contacts", _contacts_series), ("imu", _imu_series), ("base", _base_series))
"""The roles load_log reads from their own topics and pairs with each joint sample, in reading
order; a role the profile marks `estimate` (contacts, base) is estimated after pairing instead.
The command, whose value depends on the joint sample it acts on (CommandReader), is read after
them."""


def _paired(values: np.ndarray, fill: Any, idx: np.ndarray) -> np.ndarray:
    """values[idx] per joint sample; `fill` where idx < 0 (no partner)."""
    out = np.empty((len(idx), *values.shape[1:]), dtype=values.dtype)
    out[:] = fill
    has = idx >= 0
    out[has] = values[idx[has]]
    return out


def _span(t: np.ndarray) -> str:
    return f"{t[0] * 1e-9:.3f}–{t[-1] * 1e-9:.3f} s" if len(t) else "none"


def _require(role: str, topic: str, idx: np.ndarray, src_t: np.ndarray, tj: np.ndarray, max_age_s: float,
             what: str = "at or before") -> None:
    if not (idx >= 0).any():
        raise BagError(f"{role} ({topic}): no message within {max_age_s:g} s {what} any joint-state sample "
                       f"({role} stamps {_span(src_t)}, joint states {_span(tj)})")


def load_log(robot: RobotDescription, path: str | os.PathLike, profile: RobotProfile | None = None,
             max_age_s: float = 0.02) -> SensorLog:
    """Read one bag through the profile into a bagio.SensorLog (no /sim/ topic is read).

    Samples are taken at the joint-state stamps; each other role is paired by the pairing
    module's rule: the latest message at or before the stamp (the command strictly before
    it: a command stamped t was computed from the sample at t and acts after it), at most
    max(max_age_s, 2.5 of that topic's periods) old. Malformed messages are dropped and counted by role and reason.
    Stamps: every topic is ordered by its stamps (messages that arrived out of order are
    sorted, not refused, and reported in stamp_report); of joint-state messages sharing a
    stamp the last is used and the others are counted in `rejected`.
    """
    profile = profile if profile is not None else load_profile()
    inputs = profile.inputs
    js, base_spec, con_spec = inputs["joint_state"], inputs["base"], inputs["contacts"]
    imu_spec, cmd_spec = inputs.get("imu"), inputs.get("command")
    wanted: dict[str, tuple[str, str, str]] = {js["topic"]: ("joint_state", js["type"], js["stamp"])}
    if "topic" in base_spec:
        wanted[base_spec["topic"]] = ("base", base_spec["type"], base_spec["stamp"])
    elif "pose_topic" in base_spec:
        wanted[base_spec["pose_topic"]] = ("base", base_spec["pose_type"], base_spec["stamp"])
        wanted[base_spec["twist_topic"]] = ("base", base_spec["twist_type"], base_spec["stamp"])
    if imu_spec is not None:
        wanted[imu_spec["topic"]] = ("imu", imu_spec["type"], imu_spec["stamp"])
    if "topics" in con_spec:
        for t in con_spec["topics"].values():
            wanted[t] = ("contacts", con_spec["type"], con_spec["stamp"])
    elif "topic" in con_spec and con_spec["topic"] != js["topic"]:
        wanted[con_spec["topic"]] = ("contacts", con_spec["type"], con_spec["stamp"])
    if cmd_spec is not None:
        if cmd_spec["topic"] in wanted:
            raise BagError(f"command: topic {cmd_spec['topic']} is already the {wanted[cmd_spec['topic']][0]} input")
        wanted[cmd_spec["topic"]] = ("command", cmd_spec["type"], cmd_spec["stamp"])
    rej = _Rejections()
    tops = read_topics(path, wanted, rej)
    warnings: list[str] = []
    sources: dict[str, str] = {}

    # joint states (the sample instants)
    jtop = tops[js["topic"]]
    jr = JointReader(robot, profile, jtop.topic, need_effort=profile.torque_source != "none")
    tj, joints = _convert(jtop, rej, jr)
    keep = np.append(tj[1:] != tj[:-1], True)  # duplicated stamps: keep the last one
    if not keep.all():  # every drop is counted
        rej.add("joint_state", jtop.topic, "duplicated stamp (the last message of the stamp is used)",
                int((~keep).sum()))
    tj, joints = tj[keep], [j for j, k in zip(joints, keep) if k]
    qj = np.array([j[0] for j in joints])
    qdj = np.array([j[1] for j in joints])
    tau = np.array([j[2] for j in joints])
    stamp_report = dict(jtop.report)
    rate = measure_rate(tj * 1e-9).rate_hz
    if not np.isfinite(rate):
        raise BagError(f"joint_state ({jtop.topic}): fewer than two distinct stamps; no sample rate")
    stamp_report["rate_hz"] = float(rate)
    extra = sorted(jr.extra)
    expected = [e for e in extra if e in profile.ignore_joints]
    surprise = [e for e in extra if e not in profile.ignore_joints]
    sources["joint_state"] = f"topic {jtop.topic} ({JOINT_STATE}), {rate:.1f} Hz"
    if expected:
        sources["joint_state"] += f"; ignored entries {expected}"
    if surprise:
        warnings.append(f"joint_state ({jtop.topic}): entries {surprise} are not joints of the URDF and were "
                        "ignored (list them in ignore_joints)")
    n = len(tj)
    ok = np.ones(n, dtype=bool)
    stale: dict[str, int] = {}

    def hold(role: str, topic: str, src_t: np.ndarray) -> np.ndarray:
        """Each joint sample's partner of `role` (pairing: the rule and its age limit)."""
        strict, limit = is_strict(role), age_limit_ns(max_age_s, src_t)
        idx = partner_indices(src_t, tj, limit, strict=strict)
        _require(role, topic, idx, src_t, tj, limit * 1e-9, "before" if strict else "at or before")
        stale[role] = int((idx < 0).sum())
        return idx

    # the measured roles, each paired with every joint sample (MEASURED_ROLES)
    paired: dict[str, tuple[np.ndarray, ...]] = {}
    for role, read_series in MEASURED_ROLES:
        spec = inputs.get(role)
        if spec is None or "estimate" in spec:
            continue
        series = read_series(robot, spec, tops, rej, warnings, jtop)
        sources[role] = series.source
        idx = hold(role, series.topic, series.t)
        ok &= idx >= 0
        paired[role] = tuple(_paired(v, fill, idx) for v, fill in zip(series.values, series.missing))
    # command
    u_observed = cmd_spec is not None
    u = tau.copy()
    if cmd_spec is not None:
        cmd = _Command(robot, profile, cmd_spec, tops, rej)
        iu = hold("command", cmd.topic, cmd.t)
        ok &= iu >= 0
        for k in np.flatnonzero(iu >= 0):
            u[k] = cmd.u(iu[k], qj[k], qdj[k], (tj[k] - cmd.t[iu[k]]) * 1e-9)
        sources["command"] = cmd.desc
    # keep the samples that have every measured role
    if not ok.any():
        raise BagError(f"bag {path}: no joint-state sample has every input within its age limit "
                       f"(missing per role: {stale})")
    sel = np.flatnonzero(ok)
    tj, qj, qdj, tau, u = tj[sel], qj[sel], qdj[sel], tau[sel], u[sel]
    n = len(tj)
    paired = {role: tuple(a[sel] for a in arrays) for role, arrays in paired.items()}
    contacts = paired["contacts"][0] if "contacts" in paired else None
    imu, base = paired.get("imu"), paired.get("base")  # (orientation x y z w, gyro); (position, orientation, twist)
    if cmd_spec is not None and profile.torque_source != "none":  # what the actuator lag reads (diagnosis)
        stamp_report["command_sampling"] = _command_sampling(robot, cmd, iu[sel], tj, qj, qdj, tau, u, rate)
    if profile.torque_source == "none":
        if cmd_spec is None:
            raise BagError("torque_source none needs inputs.command (the only torque left is the command)")
        tau = u.copy()
        warnings.append("torque_source none: the command is used as the joint torque; the actuation error "
                        "is not observable")
        u_observed = False
    t_s = tj * 1e-9
    # estimated roles: contacts need q (base orientation from the IMU or the base input), the base needs contacts
    if contacts is None:
        from ciml_learning.core.estimation import estimate_contacts

        q_est = np.hstack([base[0] if base is not None else np.zeros((n, 3)),
                           base[1] if base is not None else (imu[0] if imu is not None
                                                             else np.tile([0, 0, 0, 1.0], (n, 1))),
                           qj])
        v_est = np.hstack([base[2] if base is not None else
                           np.hstack([np.zeros((n, 3)), imu[1] if imu is not None else np.zeros((n, 3))]),
                           qdj])
        kw = {k: con_spec[k] for k in ("threshold", "hysteresis") if k in con_spec}
        contacts, _ = estimate_contacts(robot, t_s, q_est, v_est, tau, **kw)
        contacts = np.asarray(contacts, dtype=bool)
        sources["contacts"] = "estimated from the legs' dynamics (estimation.estimate_contacts)"
    if base is None:
        from ciml_learning.core.estimation import estimate_base

        assert imu is not None and imu_spec is not None  # the profile allows imu_legs only with inputs.imu
        frame = {"imu_frame": imu_spec["frame"]} if "frame" in imu_spec else {}
        base = estimate_base(robot, t_s, qj, qdj, imu[0], imu[1], contacts, **frame)
        sources["base"] = ("estimated: orientation and angular velocity from the IMU, linear velocity from the "
                           "stance legs (estimation.estimate_base)")
    # torque that follows the command: Γ = τ − u carries no actuator information
    corr = None
    if u_observed:
        r = _correlations(tau, u)
        corr = {j: (None if not np.isfinite(x) else float(x)) for j, x in zip(robot.joint_names, r)}
        fin = r[np.isfinite(r)]
        if len(fin) and np.median(fin) > TORQUE_FOLLOWS_COMMAND_R:
            warnings.append(f"measured torque follows the command (median r = {np.median(fin):.4f} over joints > "
                            f"{TORQUE_FOLLOWS_COMMAND_R}): the actuation error Γ = τ − u is zero or not observable")
        if profile.torque_source == "current_estimate":
            warnings.append("torque_source current_estimate: the measured torque is motor current × torque "
                            "constant; the actuation error Γ = τ − u shows only what the estimate sees")
    elif cmd_spec is None:
        warnings.append("no command input: the actuation error Γ = τ − u is not observable; only the rigid-body "
                        "error is learned and diagnosed")
    q = np.hstack([base[0], base[1], qj])
    v = np.hstack([base[2], qdj])
    rejected = dict(rej.counts)
    n_stale = int((~ok).sum())
    if n_stale:
        rejected["stale_or_missing"] = n_stale
    stamp_report["stale_by_role"] = stale
    # every input topic's own rate and stamp problems (e.g. commands at 250 Hz under 1 kHz joint states)
    stamp_report["topics"] = {top.topic: {"role": top.role, "rate_hz": top.report["rate_hz"],
                                          "problems": top.report["problems"]} for top in tops.values()}
    return SensorLog(bag=str(path), t=t_s, q=q, v=v, tau=tau, u=u, contacts=np.asarray(contacts, dtype=bool),
                     rejected=rejected, rate_hz=float(rate), stamp_report=stamp_report, u_observed=u_observed,
                     sources=sources, warnings=warnings, torque_command_correlation=corr)


PHASE_BINS = 20
"""Bins of the command period in which command_sampling reports where the samples fall."""


def _command_sampling(robot: RobotDescription, cmd: _Command, idx: np.ndarray, tj: np.ndarray, qj: np.ndarray,
                      qdj: np.ndarray, tau: np.ndarray, u: np.ndarray, rate: float) -> dict:
    """How the log samples its command, which sets what a lag's coefficient reads
    (diagnosis.identification.lag_reading):

    - period_s: the command period Δ (median step of the command stamps);
    - phases: [phase, share] per occupied bin of the period: the samples' mean φ/Δ ∈ (0, 1], φ the
      time since the stamp of the command paired with them (1: on a command instant), and the
      share of the samples in the bin;
    - staircase_share: per joint and "all", the share f of the command's rate (projected on the
      torque's, both low-passed: filters.derivative_taps) made at the command updates — between two
      samples, the new command minus the old one at the same state and time; the rest is the joint
      loop's feedback on the measured state, continuous in time. Clipped to [0, 1]; 1 where the
      log is too short to tell.
    """
    period = float(np.median(np.diff(cmd.t))) * 1e-9 if len(cmd.t) > 1 else float("nan")
    if not period > 0:
        return {}
    phase = np.clip((tj - cmd.t[idx]) * 1e-9 / period, 1e-9, 1.0)  # a lost command: held, read as at its end
    k = np.minimum((np.ceil(phase * PHASE_BINS) - 1).astype(int), PHASE_BINS - 1)
    phases = [[float(phase[k == b].mean()), float(np.mean(k == b))] for b in range(PHASE_BINS) if np.any(k == b)]
    steps = np.zeros_like(u)
    for i in np.flatnonzero(idx[1:] != idx[:-1]) + 1:
        steps[i] = u[i] - cmd.u(idx[i - 1], qj[i], qdj[i], (tj[i] - cmd.t[idx[i - 1]]) * 1e-9)
    num = den = np.zeros(u.shape[1])
    try:
        taps = derivative_taps(rate)
        tau_dot, ok = filter_offline(tau, taps)
        if ok.any():
            num = np.sum(filter_offline(np.cumsum(steps, axis=0), taps)[0][ok] * tau_dot[ok], axis=0)
            den = np.sum(filter_offline(u, taps)[0][ok] * tau_dot[ok], axis=0)
    except ValueError:  # a rate too low for the low-pass: nothing measured
        pass

    def share(a, b) -> float:
        return float(np.clip(a / b, 0.0, 1.0)) if b > 0 else 1.0
    out = {j: share(a, b) for j, a, b in zip(robot.joint_names, num, den)}
    out["all"] = share(num.sum(), den.sum())
    return {"samples": len(tj), "period_s": period, "phases": phases, "staircase_share": out}


def _correlations(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per column Pearson r of a and b (NaN where either is constant)."""
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    den = np.sqrt((a * a).sum(axis=0) * (b * b).sum(axis=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, (a * b).sum(axis=0) / np.where(den > 0, den, 1.0), np.nan)
