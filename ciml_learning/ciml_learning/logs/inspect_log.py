"""`ciml inspect --bag BAG [--out profile.yaml]`: what a bag holds and how CIML can read it.

Lists every topic with its type, message count, measured rate (header stamps; the
recording time for headerless types) and its problems (zero and duplicated stamps, zero
quaternions); guesses which topic fills each role of the robot profile (by type, then by
name: JointState → joint_state, Odometry → base, Imu → imu, per-foot arrays/entries named
foot/contact/force → contacts, effort arrays or low-level commands → command); drafts what
the log needs instead of what it cannot use (an odometry with zero quaternions is not the
base: the IMU and the legs are; an IMU with zero quaternions gets `orientation: estimate`;
zero header stamps get `stamp: log`) and writes a draft profile (atomically) for the user to
edit (docs/ROBOT_PROFILE.md). With --robot/--urdf the joint and foot names are
checked against the URDF. Pure module: no rclpy.
"""
from __future__ import annotations

import re
from typing import Any

import numpy as np

from ciml_learning.core.profile import CONTACT_STATE, IMU, JOINT_STATE, ODOMETRY, TORQUE_COMMAND, WRENCH
from ciml_learning.core.stamps import measure_rate
from ciml_learning.logs.loginputs import message_stamp_ns

MAX_MESSAGES = 20_000
"""Messages deserialised per topic for the statistics (rates settle long before)."""
FOOT_WORDS = re.compile(r"foot|feet|contact|force|toe", re.IGNORECASE)
COMMAND_WORDS = re.compile(r"command|cmd|effort|torque", re.IGNORECASE)
ARRAYS = ("std_msgs/msg/Float64MultiArray", "std_msgs/msg/Float32MultiArray", "std_msgs/msg/Int16MultiArray",
          "std_msgs/msg/Int32MultiArray", "std_msgs/msg/UInt8MultiArray", "std_msgs/msg/ByteMultiArray")
CONTACT_WEIGHT_SHARE = 0.15
"""Draft contact threshold: a foot carrying this share of the robot's weight is in contact."""
CONTACT_HYSTERESIS_SHARE = 0.10
"""Draft hysteresis, as a share of the weight (out of contact below 5 % of it)."""
WEIGHT_AGREEMENT = 0.25
"""Relative difference between the feet's mean summed reading and m g beyond which the readings are
taken to be in another unit (the draft then uses the readings' own weight)."""
GRAVITY = 9.81  # [m/s²]
PD_NAMES = {"q_des": ("q", "q_des", "position"), "dq_des": ("dq", "dq_des", "velocity"), "kp": ("kp", "stiffness"),
            "kd": ("kd", "damping"), "tau_ff": ("tau", "tau_ff", "effort", "torque")}


def _read(path: str) -> tuple[list[dict], dict[str, list]]:
    """Per topic: {topic, type, count} and the first MAX_MESSAGES (stamp ns, msg)."""
    from rosbags.highlevel import AnyReaderError

    from ciml_learning.logs.bagio import BagError, open_reader

    reader = open_reader([path])
    msgs: dict[str, list] = {}
    try:
        topics: dict[str, dict[str, Any]] = {}
        for c in reader.connections:
            d = topics.setdefault(c.topic, {"topic": c.topic, "type": c.msgtype, "count": 0})
            d["count"] += int(c.msgcount)
        for conn, log_ns, raw in reader.messages():
            lst = msgs.setdefault(conn.topic, [])
            if len(lst) < MAX_MESSAGES:
                msg = reader.deserialize(raw, conn.msgtype)
                lst.append((message_stamp_ns(msg, log_ns, "header"), log_ns, msg))
    except (AnyReaderError, EOFError, ValueError, KeyError) as err:
        raise BagError(f"bag {path} is truncated or corrupt ({type(err).__name__}: {err})") from err
    finally:
        reader.close()
    return sorted(topics.values(), key=lambda d: d["topic"]), msgs


def _orientation(msg):
    """The quaternion a message carries as its orientation (Imu, Odometry, Pose*), else None."""
    for path in ("orientation", "pose.pose.orientation", "pose.orientation"):
        o = msg
        for attr in path.split("."):
            o = getattr(o, attr, None)
        if o is not None and hasattr(o, "w"):
            return o
    return None


def _stats(items: list) -> dict:
    """Rate and stamp problems of a topic's messages, zero stamps, duplicated stamps and zero
    quaternions (a driver that never fills the orientation) counted per topic."""
    stamps = np.array([s for s, _, _ in items], dtype=float) * 1e-9
    rep = measure_rate(stamps)
    headerless = not hasattr(items[0][2], "header") if items else True
    quats = [o for o in (_orientation(m) for _, _, m in items) if o is not None]
    zero_q = sum(np.linalg.norm([o.x, o.y, o.z, o.w]) < 1e-6 for o in quats)
    problems = rep.problems() + ([f"{zero_q} zero quaternions"] if zero_q else [])
    return {"rate_hz": None if not np.isfinite(rep.rate_hz) else round(rep.rate_hz, 2),
            "stamps": "recording time (no header)" if headerless else "header.stamp",
            "zero_stamps": 0 if headerless else rep.zero_stamps, "duplicated_stamps": rep.duplicates,
            "zero_quaternions": int(zero_q), "problems": problems}


def _foot_names(names: list[str], feet: tuple[str, ...] | None) -> list[str]:
    if feet:
        return [n for n in names if n in feet or n.lower() in {f.lower() for f in feet}]
    return [n for n in names if FOOT_WORDS.search(n)]


def _threshold_from(values: np.ndarray, mass: float | None = None) -> tuple[float, float, str]:
    """A draft contact threshold and hysteresis for per-foot force readings (samples × feet), and why.

    A foot is relied on as a contact once it carries CONTACT_WEIGHT_SHARE of the robot's weight
    W (and released below (CONTACT_WEIGHT_SHARE − CONTACT_HYSTERESIS_SHARE) W): the data's
    midpoint sits in the middle of the stance load and drops early and late stance. W is m g
    with the robot's mass; without it — or when the readings disagree with m g by more than
    WEIGHT_AGREEMENT (another unit, a scale) — W is the mean of the feet's summed reading: over a
    log the feet carry the weight on average (vertical momentum balance), in the sensor's unit."""
    total = float(np.nanmean(np.nansum(values, axis=1))) if values.size else float("nan")
    weight, why = total, f"the feet's mean summed reading ({total:.1f})"
    if mass is not None:
        mg = mass * GRAVITY
        if np.isfinite(total) and abs(total - mg) <= WEIGHT_AGREEMENT * mg:
            weight, why = mg, f"the robot's weight m g = {mg:.1f} N (the feet's mean summed reading: {total:.1f})"
        elif not np.isfinite(total) or total <= 0:
            weight, why = mg, f"the robot's weight m g = {mg:.1f} N"
        else:
            why += f", not the robot's weight m g = {mg:.1f} N: check the sensor's unit"
    if not np.isfinite(weight) or weight <= 0:
        return 0.0, 0.0, "no positive readings: set the threshold [N] by hand"
    return (float(round(CONTACT_WEIGHT_SHARE * weight, 3)), float(round(CONTACT_HYSTERESIS_SHARE * weight, 3)),
            f"threshold {CONTACT_WEIGHT_SHARE:.0%} and hysteresis {CONTACT_HYSTERESIS_SHARE:.0%} of {why}")


def _twist_frame(items: list) -> tuple[str, str]:
    """Odometry twist frame guessed from the data: is twist.linear the pose's world-frame
    velocity, or that velocity rotated into the body frame?"""
    from scipy.spatial.transform import Rotation

    if len(items) < 10:
        return "child", "too few messages to tell; REP 105 says child (body) frame"
    t = np.array([s for s, _, _ in items]) * 1e-9
    p = np.array([[m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z] for _, _, m in items])
    qs = np.array([[m.pose.pose.orientation.x, m.pose.pose.orientation.y, m.pose.pose.orientation.z,
                    m.pose.pose.orientation.w] for _, _, m in items])
    v = np.array([[m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z] for _, _, m in items])
    ok = (np.diff(t) > 0)
    if ok.sum() < 5 or np.any(np.linalg.norm(qs, axis=1) < 1e-6):
        return "child", "cannot compare with the pose; REP 105 says child (body) frame"
    vw = np.gradient(p, t, axis=0)
    body = Rotation.from_quat(qs).inv().apply(vw)
    e_world, e_body = np.sqrt(np.mean((v - vw) ** 2)), np.sqrt(np.mean((v - body) ** 2))
    if np.sqrt(np.mean(vw ** 2)) < 1e-3:
        return "child", "the base hardly moves; cannot tell (REP 105: child frame)"
    if e_world < 0.5 * e_body:
        return "world", f"twist.linear matches the pose's world-frame velocity (rms {e_world:.3f} vs {e_body:.3f} m/s)"
    return "child", f"twist.linear matches the body-frame velocity (rms {e_body:.3f} vs {e_world:.3f} m/s)"


def _pd_fields(msg) -> dict[str, str] | None:
    """Field paths of a low-level PD command: an array of per-motor records with q/kp/… attributes."""
    for attr in (a for a in dir(msg) if not a.startswith("_")):
        val = getattr(msg, attr, None)
        if isinstance(val, (list, tuple)) and val and hasattr(val[0], "__dataclass_fields__"):
            fields = set(val[0].__dataclass_fields__)
            out = {}
            for key, names in PD_NAMES.items():
                hit = next((n for n in names if n in fields), None)
                if hit:
                    out[key] = f"{attr}[*].{hit}"
            if {"q_des", "kp"} <= set(out) or "tau_ff" in out:
                return out
    return None


def inspect_bag(path: str, joint_names: tuple[str, ...] | None = None, feet: tuple[str, ...] | None = None,
                mass: float | None = None) -> dict:
    """Topics, stamp statistics and role guesses of one bag; `joint_names`/`feet` (a URDF's)
    sharpen the guesses, `mass` [kg] (the robot's) sets the drafted contact threshold
    (_threshold_from). Returns {"topics": [...], "roles": {role: {...}}, "notes": [...]}."""
    topics, msgs = _read(path)
    for d in topics:
        d.update(_stats(msgs[d["topic"]]) if msgs.get(d["topic"]) else
                 {"rate_hz": None, "zero_stamps": 0, "duplicated_stamps": 0, "zero_quaternions": 0,
                  "problems": ["empty"]})
    by_type: dict[str, list[dict]] = {}
    for d in topics:
        by_type.setdefault(d["type"], []).append(d)
    roles: dict[str, dict[str, Any]] = {}
    notes: list[str] = []

    def first(items):
        return items[0][2] if items else None

    # joint states: the JointState with the most entries that is not a command
    js = [d for d in by_type.get(JOINT_STATE, [])
          if not COMMAND_WORDS.search(d["topic"]) or "joint_states" in d["topic"]]
    js.sort(key=lambda d: ("joint_states" not in d["topic"], -len(getattr(first(msgs.get(d["topic"])), "name", []))))
    extra_names: list[str] = []
    if js:
        d = js[0]
        names = list(first(msgs[d["topic"]]).name)
        roles["joint_state"] = {"spec": {"topic": d["topic"], "type": JOINT_STATE},
                                "why": f"{JOINT_STATE} with {len(names)} entries at {d['rate_hz']} Hz"}
        if joint_names:
            extra_names = [n for n in names if n not in joint_names]
            missing = [j for j in joint_names if j not in names]
            if missing:
                notes.append(f"joint_state: URDF joints {missing} are not in {d['topic']}; map the log's names "
                             f"to them in joint_map (the log has {[n for n in names if n not in joint_names]})")
        else:
            extra_names = _foot_names(names, feet)
    else:
        notes.append("joint_state: no sensor_msgs/msg/JointState topic; CIML needs one")
    # contacts
    if by_type.get(CONTACT_STATE):
        d = by_type[CONTACT_STATE][0]
        roles["contacts"] = {"spec": {"topic": d["topic"], "type": CONTACT_STATE}, "why": "CIML's contact type"}
    else:
        foot_entries = _foot_names(extra_names, feet) if extra_names else []
        arrays = [d for t in ARRAYS for d in by_type.get(t, []) if FOOT_WORDS.search(d["topic"])]
        wrenches = [d for d in by_type.get(WRENCH, []) if FOOT_WORDS.search(d["topic"]) or
                    (feet and any(f.lower() in d["topic"].lower() for f in feet))]
        if foot_entries and "joint_state" in roles:
            top = roles["joint_state"]["spec"]["topic"]
            items = msgs[top]
            idx = [list(items[0][2].name).index(n) for n in foot_entries]
            vals = np.array([np.asarray(m.effort, float)[idx] for _, _, m in items if len(m.effort) == len(m.name)])
            thr, hyst, how = _threshold_from(vals, mass) if len(vals) else (0.0, 0.0, "no readings")
            roles["contacts"] = {"spec": {"topic": top, "type": JOINT_STATE, "field": "effort",
                                          "names": foot_entries, "threshold": thr, "hysteresis": hyst},
                                 "why": f"JointState entries {foot_entries} look like foot sensors; {how} — check it"}
        elif arrays:
            d = arrays[0]
            vals = np.array([np.asarray(m.data, float) for _, _, m in msgs[d["topic"]]])
            thr, hyst, how = _threshold_from(vals, mass)
            roles["contacts"] = {"spec": {"topic": d["topic"], "type": d["type"], "field": "data",
                                          "threshold": thr, "hysteresis": hyst},
                                 "why": f"per-foot array ({vals.shape[1]} values) named like foot forces; the "
                                        "values must be in the profile's feet order (else add order:); "
                                        f"{how} — check it"}
        elif len(wrenches) >= 2:
            roles["contacts"] = {"spec": {"topics": {f"FOOT_{i}": d["topic"] for i, d in enumerate(wrenches)},
                                          "type": WRENCH, "field": "wrench.force.z", "threshold": 20.0,
                                          "hysteresis": 5.0},
                                 "why": "WrenchStamped per foot; rename the keys to the URDF's foot frames; "
                                        "threshold is a placeholder [N]"}
        else:
            roles["contacts"] = {"spec": {"estimate": "dynamics"},
                                 "why": "no contact or foot-force topic: estimated from the legs' dynamics"}
    # imu: a quaternion that is zero is estimated from gyro and accelerometer (loginputs)
    if by_type.get(IMU):
        d = by_type[IMU][0]
        roles["imu"] = {"spec": {"topic": d["topic"], "type": IMU}, "why": f"{IMU} at {d['rate_hz']} Hz"}
        if d["zero_quaternions"]:
            roles["imu"]["spec"]["orientation"] = "estimate"
            roles["imu"]["why"] += (f"; {d['zero_quaternions']} zero quaternions: orientation estimated from gyro "
                                    "and accelerometer")
    # base: an odometry without orientation cannot place the base; the IMU and the legs can
    odometry = sorted((d for d in by_type.get(ODOMETRY, []) if not d["zero_quaternions"]), key=lambda d: -d["count"])
    for d in by_type.get(ODOMETRY, []):
        if d["zero_quaternions"]:
            notes.append(f"base: {d['topic']} has {d['zero_quaternions']} zero quaternions (no orientation); "
                         "not used as the base" + (", estimated from the IMU and the stance legs instead"
                                                   if "imu" in roles and not odometry else ""))
    if odometry:
        d = odometry[0]
        frame, why = _twist_frame(msgs[d["topic"]])
        roles["base"] = {"spec": {"topic": d["topic"], "type": ODOMETRY, "twist_frame": frame},
                         "why": f"{ODOMETRY} at {d['rate_hz']} Hz; twist_frame {frame}: {why}"}
    elif by_type.get("geometry_msgs/msg/PoseStamped") and by_type.get("geometry_msgs/msg/TwistStamped"):
        pt, tt = by_type["geometry_msgs/msg/PoseStamped"][0], by_type["geometry_msgs/msg/TwistStamped"][0]
        roles["base"] = {"spec": {"pose_topic": pt["topic"], "twist_topic": tt["topic"], "twist_frame": "child"},
                         "why": "pose + twist topics; check the twist's frame (header.frame_id "
                                f"{first(msgs[tt['topic']]).header.frame_id!r})"}
    elif "imu" in roles:
        roles["base"] = {"spec": {"estimate": "imu_legs"},
                         "why": "no odometry: orientation from the IMU, velocity from the stance legs"}
    else:
        notes.append("base: no odometry, pose or IMU topic; CIML cannot place the base")
    # command
    jnames = list(joint_names) if joint_names else None
    if by_type.get(TORQUE_COMMAND):
        d = by_type[TORQUE_COMMAND][0]
        roles["command"] = {"spec": {"topic": d["topic"], "type": TORQUE_COMMAND}, "why": "CIML's command type"}
    else:
        cands = []
        for d in topics:
            if d["topic"] == roles.get("joint_state", {}).get("spec", {}).get("topic"):
                continue
            m = first(msgs.get(d["topic"], []))
            if d["type"] == JOINT_STATE and COMMAND_WORDS.search(d["topic"]):
                cands.append((0, d, {"topic": d["topic"], "type": JOINT_STATE, "field": "effort"},
                              "JointState named like a command: its effort entries"))
            elif d["type"] in ARRAYS and COMMAND_WORDS.search(d["topic"]) and not FOOT_WORDS.search(d["topic"]):
                n = len(m.data) if m is not None else 0
                joints = jnames if jnames and len(jnames) == n else [f"JOINT_{i}" for i in range(n)]
                cands.append((1, d, {"topic": d["topic"], "type": d["type"], "field": "data", "joints": joints},
                              f"effort array ({n} values) named like a command; list the URDF joints in the "
                              "array's order"))
            elif m is not None and (pd := _pd_fields(m)) and d["type"] not in (JOINT_STATE, ODOMETRY, IMU):
                joints = jnames or ["JOINT_0", "..."]
                cands.append((2, d, {"topic": d["topic"], "type": d["type"], "joints": joints, "fields": pd},
                              "low-level PD command (per-motor records); list the URDF joints in motor order"))
        if cands:
            cands.sort(key=lambda c: c[0])
            _, d, spec, why = cands[0]
            roles["command"] = {"spec": spec, "why": f"{why} ({d['rate_hz']} Hz)"}
        else:
            notes.append("command: none found; the actuation error will be reported not observable")
    # a role whose header stamps are zero is timed by the recording (stamp: log)
    by_topic = {d["topic"]: d for d in topics}
    for r in roles.values():
        top = by_topic.get(r["spec"].get("topic", ""))
        if top is not None and top["zero_stamps"] and top["stamps"] == "header.stamp":
            r["spec"]["stamp"] = "log"
            r["why"] += f"; {top['zero_stamps']} zero header stamps: timed by the recording (stamp: log)"
    return {"bag": str(path), "topics": topics, "roles": roles, "notes": notes, "extra_joint_entries": extra_names}


def draft_profile(report: dict, name: str, urdf: str | None, feet: tuple[str, ...] | None) -> dict:
    """A profile mapping from an inspect report (docs/ROBOT_PROFILE.md)."""
    inputs = {role: report["roles"][role]["spec"] for role in ("joint_state", "base", "imu", "contacts", "command")
              if role in report["roles"]}
    return {"format": 1, "name": name, "urdf": urdf or "TODO/path/to/robot.urdf",
            "feet": list(feet) if feet else ["TODO_foot_frame_1", "TODO_foot_frame_2", "TODO_foot_frame_3",
                                              "TODO_foot_frame_4"],
            "joint_map": {}, "ignore_joints": list(report.get("extra_joint_entries", [])), "torque_limits": {},
            "torque_source": "sensor", "inputs": inputs}


def profile_yaml(profile: dict, report: dict) -> str:
    import yaml

    lines = [f"# Draft robot profile from 'ciml inspect --bag {report['bag']}'. Check every line, then",
             "# pass it as --robot FILE. Schema: docs/ROBOT_PROFILE.md",
             "# torque_source: sensor (torque sensors), current_estimate (motor current), none.",
             "# Why each role was chosen:"]
    lines += [f"#   {role}: {r['why']}" for role, r in report["roles"].items()]
    lines += [f"# NOTE {n}" for n in report["notes"]]
    return "\n".join(lines) + "\n" + yaml.safe_dump(profile, sort_keys=False, default_flow_style=None, width=110)
