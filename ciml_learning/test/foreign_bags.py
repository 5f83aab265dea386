"""Tiny robot logs in foreign layouts (MCAP, db3, ROS 1), written with rosbags' writers.

A go1-like log: JointState with four extra foot-sensor entries, Odometry with a world-frame
twist, per-foot forces as an array, a Unitree-like low-level command (a message type CIML
does not know, readable only from the bag's embedded definition). Known values so the
reader's output can be checked exactly.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

LOWCMD_MSGS = {
    "unitree_go/msg/MotorCmd": "uint8 mode\nfloat32 q\nfloat32 dq\nfloat32 tau\nfloat32 kp\nfloat32 kd\n",
    "unitree_go/msg/LowCmd": "uint8 level_flag\nunitree_go/MotorCmd[20] motor_cmd\n",
}
UNITREE_ORDER = ["FR_hip_joint", "FR_thigh_joint", "FR_calf_joint", "FL_hip_joint", "FL_thigh_joint", "FL_calf_joint",
                 "RR_hip_joint", "RR_thigh_joint", "RR_calf_joint", "RL_hip_joint", "RL_thigh_joint", "RL_calf_joint"]
FEET = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]
YAW = np.pi / 2  # base turned 90°: a world-frame twist differs from the body-frame one
V_WORLD = np.array([0.3, 0.0, 0.0])
KP, KD, Q_OFFSET, TAU_FF = 20.0, 0.5, 0.01, 1.0


def store(ros1: bool = False):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    s = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_JAZZY)
    types = {}
    for name, text in LOWCMD_MSGS.items():
        types.update(get_types_from_msg(text, name))
    s.register(types)
    return s


def go1_signals(robot, rate_hz: float, seconds: float):
    """Known joint trajectories (URDF order), torques, foot forces at rate_hz."""
    t = np.arange(int(seconds * rate_hz)) / rate_hz + 1.0
    ph = np.arange(robot.n_joints)[None, :] * 0.4
    w = 2 * np.pi * 1.5
    q = robot.standing_joints[None, :] + 0.1 * np.sin(w * t[:, None] + ph)
    qd = 0.1 * w * np.cos(w * t[:, None] + ph)
    tau = 3.0 * np.sin(2 * np.pi * 0.7 * t[:, None] + 2 * ph)
    force = np.full((len(t), 4), 100.0)
    force[:, 0] = np.where((t % 0.5) < 0.25, 100.0, 0.0)
    return t, q, qd, tau, force


def _header(s, ns: int, frame: str = ""):
    T = s.types["builtin_interfaces/msg/Time"]
    H = s.types["std_msgs/msg/Header"]
    kw = {"seq": 0} if "seq" in H.__dataclass_fields__ else {}
    return H(**kw, stamp=T(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000)), frame_id=frame)


def go1_messages(robot, s, rate_hz: float = 500.0, seconds: float = 1.0, *, zero_quat: bool = False,
                 zero_stamps: bool = False, with_command: bool = True, torque_is_command: bool = False):
    """(topic, type, log ns, msg) of a Unitree-like go1 log."""
    t, q, qd, tau, force = go1_signals(robot, rate_hz, seconds)
    JS = s.types["sensor_msgs/msg/JointState"]
    Odo = s.types["nav_msgs/msg/Odometry"]
    F64 = s.types["std_msgs/msg/Float64MultiArray"]
    Lay = s.types["std_msgs/msg/MultiArrayLayout"]
    g = "geometry_msgs/msg/"
    P, Qt, V = s.types[g + "Point"], s.types[g + "Quaternion"], s.types[g + "Vector3"]
    Pose, Tw = s.types[g + "Pose"], s.types[g + "Twist"]
    PwC, TwC = s.types[g + "PoseWithCovariance"], s.types[g + "TwistWithCovariance"]
    Low, Mot = s.types["unitree_go/msg/LowCmd"], s.types["unitree_go/msg/MotorCmd"]
    names = list(robot.joint_names) + FEET
    quat = [0.0, 0.0, 0.0, 0.0] if zero_quat else [0.0, 0.0, np.sin(YAW / 2), np.cos(YAW / 2)]
    out = []
    for k, tk in enumerate(t):
        ns = int(round(tk * 1e9))
        hs = 0 if zero_stamps else ns
        eff = np.r_[tau[k] if not torque_is_command else _pd(q[k], qd[k]) , force[k]]
        out.append(("/joint_states", "sensor_msgs/msg/JointState", ns,
                    JS(header=_header(s, hs), name=names, position=np.r_[q[k], np.zeros(4)],
                       velocity=np.r_[qd[k], np.zeros(4)], effort=eff)))
        pos = V_WORLD * (tk - 1.0)
        out.append(("/odom", "nav_msgs/msg/Odometry", ns, Odo(
            header=_header(s, ns, "odom"), child_frame_id="trunk",
            pose=PwC(pose=Pose(position=P(x=pos[0], y=pos[1], z=0.3), orientation=Qt(x=quat[0], y=quat[1], z=quat[2],
                                                                                      w=quat[3])),
                     covariance=np.zeros(36)),
            twist=TwC(twist=Tw(linear=V(x=V_WORLD[0], y=V_WORLD[1], z=V_WORLD[2]), angular=V(x=0.0, y=0.0, z=0.0)),
                      covariance=np.zeros(36)))))
        out.append(("/foot_force", "std_msgs/msg/Float64MultiArray", ns,
                    F64(layout=Lay(dim=[], data_offset=0), data=force[k].astype(float))))
        if with_command:
            # the command computed from this sample, stamped (recording time) 0.5 ms later
            qu = {j: (q[k][i], qd[k][i]) for i, j in enumerate(robot.joint_names)}
            motors = [Mot(mode=10, q=float(qu[j][0] + Q_OFFSET), dq=0.0, tau=TAU_FF, kp=KP, kd=KD)
                      for j in UNITREE_ORDER]
            motors += [Mot(mode=0, q=0.0, dq=0.0, tau=0.0, kp=0.0, kd=0.0)] * 8
            out.append(("/low_cmd", "unitree_go/msg/LowCmd", ns + 500_000, Low(level_flag=255, motor_cmd=motors)))
    return out


def _pd(q, qd):
    return TAU_FF + KP * Q_OFFSET - KD * qd


def write_bag(path: Path, messages, fmt: str = "mcap", ros1: bool = False) -> Path:
    """Write (topic, type, ns, msg) with rosbags: fmt mcap | sqlite3 (rosbag2) or ROS 1 (.bag)."""
    s = store(ros1)
    if ros1:
        from rosbags.rosbag1 import Writer as W1

        path = Path(path).with_suffix(".bag")
        with W1(path) as w:
            conns = {}
            for topic, typ, ns, msg in messages:
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, typ, typestore=s)
                w.write(conns[topic], ns, s.serialize_ros1(msg, typ))
        return path
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns = {}
        for topic, typ, ns, msg in messages:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=s)
            w.write(conns[topic], ns, s.serialize_cdr(msg, typ))
    return Path(path)


GO1_PROFILE = {
    "format": 1, "name": "go1_test", "urdf": "erd:go1_description/urdf/go1.urdf", "feet": FEET,
    "ignore_joints": FEET, "torque_source": "sensor",
    "inputs": {
        "joint_state": {"topic": "/joint_states", "type": "sensor_msgs/msg/JointState"},
        "base": {"topic": "/odom", "type": "nav_msgs/msg/Odometry", "twist_frame": "world"},
        "contacts": {"topic": "/foot_force", "type": "std_msgs/msg/Float64MultiArray", "field": "data",
                     "threshold": 50.0, "hysteresis": 10.0},
        "command": {"topic": "/low_cmd", "type": "unitree_go/msg/LowCmd", "joints": UNITREE_ORDER,
                    "fields": {"q_des": "motor_cmd[*].q", "dq_des": "motor_cmd[*].dq", "kp": "motor_cmd[*].kp",
                               "kd": "motor_cmd[*].kd", "tau_ff": "motor_cmd[*].tau"}},
    },
}


def imu_messages(robot, s, rate_hz: float = 500.0, seconds: float = 1.0, zero_quat: bool = False):
    """An IMU (orientation = the odometry's, or a zero quaternion; gyro zero, at rest) at the
    joint-state stamps."""
    t, *_ = go1_signals(robot, rate_hz, seconds)
    Imu, Qt = s.types["sensor_msgs/msg/Imu"], s.types["geometry_msgs/msg/Quaternion"]
    V = s.types["geometry_msgs/msg/Vector3"]
    out = []
    for tk in t:
        ns = int(round(tk * 1e9))
        out.append(("/imu", "sensor_msgs/msg/Imu", ns, Imu(
            header=_header(s, ns, "imu_link"),
            orientation=Qt(x=0.0, y=0.0, z=0.0, w=0.0) if zero_quat else
            Qt(x=0.0, y=0.0, z=float(np.sin(YAW / 2)), w=float(np.cos(YAW / 2))),
            orientation_covariance=np.zeros(9), angular_velocity=V(x=0.0, y=0.0, z=0.0),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=V(x=0.0, y=0.0, z=9.81),
            linear_acceleration_covariance=np.zeros(9))))
    return out
