"""The robot profile: which robot a log comes from and where each role lives in it.

A profile is a small YAML file (docs/ROBOT_PROFILE.md) given as `--robot profile.yaml`
(or a shipped robot's name: `--robot go1`) to every verb and as the nodes' `robot`: the
URDF and its foot frames, a joint-name map from the log's names to the URDF's, torque
limits, what the measured effort is (`torque_source`), and the input map — for each role
(joint_state, base, imu, contacts, command) a topic, its message type and, for types CIML
does not know, field paths into the message. The HyQ profile (config/robots/hyq.yaml:
CIML's own topics and types) is the default.

Loading validates everything up front; every error is one line that names the key:
``profile go1.yaml: inputs.base.twist_frame: must be one of child, world, got 'body'``.
Pure module: no rclpy.
"""
from __future__ import annotations

import glob
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription, example_robot_data_dir, load_robot

FORMAT = 1
"""Profile format version this loader reads."""

TORQUE_SOURCES = ("sensor", "current_estimate", "none")
TWIST_FRAMES = ("child", "world")
STAMP_SOURCES = ("header", "log")
IMU_ORIENTATIONS = ("auto", "estimate")
"""inputs.imu.orientation: auto — the IMU's quaternion, estimated from gyro and accelerometer when a
message has none (zero, or orientation_covariance[0] = −1 as sensor_msgs/Imu says); estimate — always
estimated (estimation.estimate_orientation)."""
ROLES = ("joint_state", "base", "imu", "contacts", "command")
PD_FIELDS = ("q_des", "dq_des", "kp", "kd", "tau_ff")

JOINT_STATE = "sensor_msgs/msg/JointState"
ODOMETRY = "nav_msgs/msg/Odometry"
IMU = "sensor_msgs/msg/Imu"
CONTACT_STATE = "ciml_msgs/msg/ContactState"
TORQUE_COMMAND = "ciml_msgs/msg/TorqueCommand"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped", ODOMETRY)
TWIST_TYPES = ("geometry_msgs/msg/TwistStamped", "geometry_msgs/msg/TwistWithCovarianceStamped", ODOMETRY)
WRENCH = "geometry_msgs/msg/WrenchStamped"


class ProfileError(CimlError):
    """A robot profile cannot be read or is inconsistent with its URDF."""


def robots_dir() -> str:
    """Folder of the shipped profiles: the source tree's config/robots, else the ament share."""
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "config", "robots")
    candidates = [here] + [os.path.join(p, "share", "ciml_learning", "config", "robots")
                           for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) + [sys.prefix] if p]
    for d in candidates:
        if glob.glob(os.path.join(d, "*.yaml")):
            return os.path.abspath(d)
    raise ProfileError("the shipped robot profiles (config/robots/*.yaml) are not installed; run make install")


def shipped_names() -> list[str]:
    """Robot names of the shipped profiles (hyq, go1, ...)."""
    return sorted(Path(p).stem for p in glob.glob(os.path.join(robots_dir(), "*.yaml")))


def shipped_profile(name: str) -> str:
    """Path of a shipped profile by robot name (hyq, go1, solo12, a1)."""
    path = os.path.join(robots_dir(), f"{name}.yaml")
    if not os.path.isfile(path):
        raise ProfileError(f"no shipped profile {name!r}; shipped: {', '.join(shipped_names())}")
    return path


def is_robot_name(spec: str) -> bool:
    """A bare name (`go1`), not a path: it names a shipped profile (a file of that name wins)."""
    return bool(spec) and os.sep not in spec and not spec.endswith((".yaml", ".yml")) and not os.path.isfile(spec)


def profile_path(spec: str | os.PathLike) -> str:
    """The profile file of --robot / a node's `robot`: a YAML path, or a shipped robot's name."""
    spec = str(spec)
    if is_robot_name(spec):
        return shipped_profile(spec)
    if not os.path.isfile(spec):
        raise ProfileError(f"profile {spec}: file not found (give a profile YAML or a shipped robot: "
                           f"{', '.join(shipped_names())})")
    return spec


@dataclass(frozen=True)
class RobotProfile:
    """A validated robot profile (docs/ROBOT_PROFILE.md); paths are absolute.

    inputs: role → its validated spec (dict); roles absent from the file are absent here
    (command absent: the actuation error is not observable).
    """

    name: str
    urdf: str
    feet: tuple[str, ...]
    joint_map: dict[str, str] = field(default_factory=dict)
    ignore_joints: tuple[str, ...] = ()
    torque_limits: dict[str, float] = field(default_factory=dict)
    torque_source: str = "sensor"
    inputs: dict[str, dict[str, Any]] = field(default_factory=dict)
    path: str | None = None

    def robot(self) -> RobotDescription:
        """The RobotDescription: URDF + feet, with the profile's torque limits applied."""
        robot = load_robot(self.urdf, list(self.feet))
        if self.torque_limits:
            unknown = [j for j in self.torque_limits if j not in robot.joint_names]
            if unknown:
                raise ProfileError(f"{self._where()}: torque_limits: joints {unknown} are not in the URDF; "
                                   f"joints are {list(robot.joint_names)}")
            limits = robot.model.effortLimit.copy()
            for j, lim in self.torque_limits.items():
                limits[6 + robot.joint_names.index(j)] = lim
            robot.model.effortLimit = limits
        unknown = sorted(set(self.joint_map.values()) - set(robot.joint_names))
        if unknown:
            raise ProfileError(f"{self._where()}: joint_map: targets {unknown} are not joints of the URDF; "
                               f"joints are {list(robot.joint_names)}")
        return robot

    def to_urdf_name(self, log_name: str) -> str:
        """A log's joint name in the URDF's terms (joint_map; identity when absent)."""
        return self.joint_map.get(log_name, log_name)

    def _where(self) -> str:
        return f"profile {self.path or self.name}"


def _err(where: str, key: str, msg: str) -> ProfileError:
    return ProfileError(f"{where}: {key}: {msg}")


def _str(where: str, key: str, v: Any) -> str:
    if not isinstance(v, str) or not v:
        raise _err(where, key, f"must be a non-empty string, got {v!r}")
    return v


def _str_list(where: str, key: str, v: Any) -> tuple[str, ...]:
    if isinstance(v, str):
        v = [s.strip() for s in v.split(",") if s.strip()]
    if not isinstance(v, (list, tuple)) or not all(isinstance(s, str) and s for s in v):
        raise _err(where, key, f"must be a list of names, got {v!r}")
    if len(set(v)) != len(v):
        raise _err(where, key, f"names repeat: {list(v)}")
    return tuple(v)


def _number(where: str, key: str, v: Any, positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v:
        raise _err(where, key, f"must be a number, got {v!r}")
    if positive and v <= 0:
        raise _err(where, key, f"must be > 0, got {v!r}")
    return float(v)


def _choice(where: str, key: str, v: Any, choices: tuple[str, ...]) -> str:
    if v not in choices:
        raise _err(where, key, f"must be one of {', '.join(choices)}, got {v!r}")
    return v


def _keys(where: str, key: str, spec: Any, allowed: tuple[str, ...]) -> dict:
    if not isinstance(spec, dict):
        raise _err(where, key, f"must be a mapping, got {spec!r}")
    extra = sorted(set(spec) - set(allowed))
    if extra:
        raise _err(where, key, f"unknown keys {extra}; allowed: {', '.join(allowed)}")
    return dict(spec)


def _topic_spec(where: str, key: str, spec: dict, default_type: str | None,
                types: tuple[str, ...] | None = None) -> dict:
    out = dict(spec)
    out["topic"] = _str(where, f"{key}.topic", spec.get("topic"))
    typ = spec.get("type", default_type)
    if typ is None:
        raise _err(where, f"{key}.type", "missing (the message type, e.g. std_msgs/msg/Float64MultiArray)")
    out["type"] = _normalise_type(_str(where, f"{key}.type", typ))
    if types is not None and out["type"] not in types:
        raise _err(where, f"{key}.type", f"must be one of {', '.join(types)}, got {out['type']!r}")
    out["stamp"] = _choice(where, f"{key}.stamp", spec.get("stamp", "header"), STAMP_SOURCES)
    return out


def _normalise_type(t: str) -> str:
    """ROS 1 style 'pkg/Type' → 'pkg/msg/Type' (rosbags' names for both bag formats)."""
    parts = t.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else t


def _threshold(where: str, key: str, spec: dict, out: dict) -> None:
    if "threshold" in spec:
        out["threshold"] = _number(where, f"{key}.threshold", spec["threshold"])
        out["hysteresis"] = _number(where, f"{key}.hysteresis", spec.get("hysteresis", 0.0))
        if out["hysteresis"] < 0:
            raise _err(where, f"{key}.hysteresis", f"must be ≥ 0, got {out['hysteresis']}")
    elif "hysteresis" in spec:
        raise _err(where, f"{key}.hysteresis", "given without a threshold")


def _validate_inputs(where: str, inputs: Any) -> dict[str, dict]:
    inputs = _keys(where, "inputs", inputs if inputs is not None else {}, ROLES)
    out: dict[str, dict] = {}
    spec: dict[str, Any]  # one role's input map (topics, types, field paths), checked
    if "joint_state" not in inputs:
        raise _err(where, "inputs.joint_state", "missing (every log needs joint states)")
    k = "inputs.joint_state"
    out["joint_state"] = _topic_spec(where, k, _keys(where, k, inputs["joint_state"], ("topic", "type", "stamp")),
                                     JOINT_STATE, (JOINT_STATE,))

    if inputs.get("imu") is not None:
        k = "inputs.imu"
        s = _keys(where, k, inputs["imu"], ("topic", "type", "stamp", "frame", "orientation"))
        out["imu"] = _topic_spec(where, k, s, IMU, (IMU,))
        if "frame" in s:
            out["imu"]["frame"] = _str(where, f"{k}.frame", s["frame"])
        out["imu"]["orientation"] = _choice(where, f"{k}.orientation", s.get("orientation", "auto"),
                                            IMU_ORIENTATIONS)

    k = "inputs.base"
    base = inputs.get("base")
    if base is None:
        raise _err(where, k, "missing: give an odometry topic, pose_topic + twist_topic, or {estimate: imu_legs}")
    b = _keys(where, k, base, ("topic", "type", "stamp", "twist_frame", "pose_topic", "twist_topic", "pose_type",
                               "twist_type", "estimate"))
    if "estimate" in b:
        if _choice(where, f"{k}.estimate", b["estimate"], ("imu_legs",)) and "imu" not in out:
            raise _err(where, k, "estimate: imu_legs needs inputs.imu")
        if set(b) - {"estimate"}:
            raise _err(where, k, f"estimate excludes {sorted(set(b) - {'estimate'})}")
        out["base"] = {"estimate": "imu_legs"}
    elif "pose_topic" in b or "twist_topic" in b:
        spec = {"pose_topic": _str(where, f"{k}.pose_topic", b.get("pose_topic")),
                "twist_topic": _str(where, f"{k}.twist_topic", b.get("twist_topic")),
                "pose_type": _normalise_type(_str(where, f"{k}.pose_type", b.get("pose_type", POSE_TYPES[0]))),
                "twist_type": _normalise_type(_str(where, f"{k}.twist_type", b.get("twist_type", TWIST_TYPES[0]))),
                "twist_frame": _choice(where, f"{k}.twist_frame", b.get("twist_frame", "child"), TWIST_FRAMES),
                "stamp": _choice(where, f"{k}.stamp", b.get("stamp", "header"), STAMP_SOURCES)}
        if spec["pose_type"] not in POSE_TYPES:
            raise _err(where, f"{k}.pose_type", f"must be one of {', '.join(POSE_TYPES)}")
        if spec["twist_type"] not in TWIST_TYPES:
            raise _err(where, f"{k}.twist_type", f"must be one of {', '.join(TWIST_TYPES)}")
        out["base"] = spec
    else:
        out["base"] = _topic_spec(where, k, {x: y for x, y in b.items() if x != "twist_frame"}, ODOMETRY, (ODOMETRY,))
        out["base"]["twist_frame"] = _choice(where, f"{k}.twist_frame", b.get("twist_frame", "child"), TWIST_FRAMES)

    k = "inputs.contacts"
    con = inputs.get("contacts")
    if con is None:
        raise _err(where, k, "missing: give a contact topic, foot forces with a threshold, or {estimate: dynamics}")
    c = _keys(where, k, con, ("topic", "type", "stamp", "field", "names", "order", "threshold", "hysteresis",
                              "topics", "estimate"))
    if "estimate" in c:
        _choice(where, f"{k}.estimate", c["estimate"], ("dynamics",))
        spec = {"estimate": "dynamics"}
        _threshold(where, k, c, spec)
        if set(c) - {"estimate", "threshold", "hysteresis"}:
            raise _err(where, k, f"estimate excludes {sorted(set(c) - {'estimate', 'threshold', 'hysteresis'})}")
    elif "topics" in c:
        topics = c["topics"]
        if not isinstance(topics, dict) or not topics:
            raise _err(where, f"{k}.topics", "must map each foot frame to its topic")
        spec = {"topics": {_str(where, f"{k}.topics", f): _str(where, f"{k}.topics.{f}", t) for f, t in topics.items()},
                "type": _normalise_type(_str(where, f"{k}.type", c.get("type", WRENCH))),
                "field": _str(where, f"{k}.field", c.get("field", "wrench.force.z" if c.get("type", WRENCH) in
                                                          (WRENCH, "geometry_msgs/WrenchStamped") else "data")),
                "stamp": _choice(where, f"{k}.stamp", c.get("stamp", "header"), STAMP_SOURCES)}
        _threshold(where, k, c, spec)
    else:
        spec = _topic_spec(where, k, c, None)
        if spec["type"] == CONTACT_STATE:
            bad = sorted(set(c) & {"field", "names", "order", "threshold", "hysteresis"})
            if bad:
                raise _err(where, k, f"{bad} do not apply to {CONTACT_STATE} (it names its feet)")
        else:
            if "field" not in c:
                raise _err(where, f"{k}.field", f"missing: which field of {spec['type']} holds the per-foot values")
            spec["field"] = _str(where, f"{k}.field", c["field"])
            if "names" in c:
                spec["names"] = _str_list(where, f"{k}.names", c["names"])
            if "order" in c:
                spec["order"] = _str_list(where, f"{k}.order", c["order"])
            if spec["type"] == JOINT_STATE and "names" not in spec:
                raise _err(where, f"{k}.names", "missing: the JointState entries that hold the foot values")
            _threshold(where, k, c, spec)
    out["contacts"] = spec

    k = "inputs.command"
    cmd = inputs.get("command")
    if cmd is not None and cmd != "none":
        m = _keys(where, k, cmd, ("topic", "type", "stamp", "field", "joints", "fields"))
        spec = _topic_spec(where, k, m, None)
        if spec["type"] == TORQUE_COMMAND:
            pass
        elif "fields" in m:
            f = _keys(where, f"{k}.fields", m["fields"], PD_FIELDS)
            missing = [x for x in ("q_des", "kp") if x not in f] if ("q_des" in f or "kp" in f) else []
            if missing:
                raise _err(where, f"{k}.fields", f"missing {missing} (u = tau_ff + kp (q_des − q) + kd (dq_des − dq))")
            if not f:
                raise _err(where, f"{k}.fields",
                           f"needs at least tau_ff or q_des + kp; allowed: {', '.join(PD_FIELDS)}")
            spec["fields"] = {x: _str(where, f"{k}.fields.{x}", y) for x, y in f.items()}
            spec["joints"] = _str_list(where, f"{k}.joints", m.get("joints"))
        else:
            default_field = "effort" if spec["type"] == JOINT_STATE else "data"
            spec["field"] = _str(where, f"{k}.field", m.get("field", default_field))
            if spec["type"] != JOINT_STATE:
                spec["joints"] = _str_list(where, f"{k}.joints", m.get("joints"))
            elif "joints" in m:
                raise _err(where, f"{k}.joints", "a JointState command names its joints itself")
        out["command"] = spec
    return out


def resolve_urdf(path: str, base_dir: str = ".") -> str:
    """A URDF reference as a path: `erd:<path>` inside example-robot-data's robots/, else the
    path (relative to base_dir: the profile's folder, or the working directory for --urdf)."""
    if path.startswith("erd:"):
        return os.path.join(example_robot_data_dir(), path[4:])
    path = os.path.expanduser(path)
    return path if os.path.isabs(path) else os.path.normpath(os.path.join(base_dir, path))


PROFILE_KEYS = ("format", "name", "urdf", "feet", "joint_map", "ignore_joints", "torque_limits", "torque_source",
                "inputs")


def profile_from_dict(data: Any, where: str = "profile", base_dir: str = ".") -> RobotProfile:
    """Validate a profile given as a mapping (as parsed from YAML)."""
    d = _keys(where, "top level", data, PROFILE_KEYS)
    fmt = d.get("format")
    if fmt != FORMAT:
        raise _err(where, "format", f"must be {FORMAT} (this CIML reads profile format {FORMAT}), got {fmt!r}")
    name = _str(where, "name", d.get("name"))
    urdf = resolve_urdf(_str(where, "urdf", d.get("urdf")), base_dir)
    if not os.path.isfile(urdf):
        raise _err(where, "urdf", f"file not found: {urdf}")
    feet = _str_list(where, "feet", d.get("feet"))
    jm = d.get("joint_map") or {}
    if not isinstance(jm, dict) or not all(isinstance(a, str) and isinstance(b, str) for a, b in jm.items()):
        raise _err(where, "joint_map", f"must map log joint names to URDF joint names, got {jm!r}")
    if len(set(jm.values())) != len(jm):
        raise _err(where, "joint_map", "two log names map to the same URDF joint")
    limits = d.get("torque_limits") or {}
    if not isinstance(limits, dict):
        raise _err(where, "torque_limits", f"must map URDF joint names to limits [Nm], got {limits!r}")
    limits = {str(j): _number(where, f"torque_limits.{j}", v, positive=True) for j, v in limits.items()}
    return RobotProfile(
        name=name, urdf=urdf, feet=feet, joint_map=dict(jm),
        ignore_joints=_str_list(where, "ignore_joints", d.get("ignore_joints") or []),
        torque_limits=limits,
        torque_source=_choice(where, "torque_source", d.get("torque_source", "sensor"), TORQUE_SOURCES),
        inputs=_validate_inputs(where, d.get("inputs")),
        path=None,
    )


def load_profile(path: str | os.PathLike | None = None) -> RobotProfile:
    """Read and validate a profile YAML, or a shipped one by robot name (HyQ when path is None)."""
    import yaml

    path = profile_path(path) if path is not None else shipped_profile("hyq")
    where = f"profile {path}"
    from ciml_learning.core.fileio import InputFileError, load_yaml_bounded

    try:  # size and alias-expansion limits
        data = load_yaml_bounded(path, where, yaml_errors=True)
    except InputFileError as err:
        raise ProfileError(str(err)) from None
    except yaml.YAMLError as err:
        line = getattr(getattr(err, "problem_mark", None), "line", None)
        raise ProfileError(f"{where}: not valid YAML{f' (line {line + 1})' if line is not None else ''}: "
                           f"{getattr(err, 'problem', err)}") from err
    prof = profile_from_dict(data, where, os.path.dirname(os.path.abspath(path)))
    return RobotProfile(**{**prof.__dict__, "path": os.path.abspath(path)})


def with_overrides(profile: RobotProfile, urdf: str | None = None,
                   feet: list[str] | tuple[str, ...] | None = None) -> RobotProfile:
    """The profile with --urdf (a path or `erd:<path>`) / --feet shortcuts applied (a URDF without
    feet keeps the profile's feet)."""
    changes: dict[str, Any] = {}
    if urdf is not None:
        path = resolve_urdf(urdf)
        if not os.path.isfile(path):
            raise ProfileError(f"--urdf: file not found: {path}" + (f" ({urdf})" if path != urdf else ""))
        changes["urdf"] = os.path.abspath(path)
    if feet is not None:
        changes["feet"] = tuple(feet)
    return RobotProfile(**{**profile.__dict__, **changes}) if changes else profile
