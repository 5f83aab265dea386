"""Robot logs in other robots' layouts, converted from a native CIML recording (tests only).

A native recording (CIML's topics and types, written by ciml_sim with its /sim/ ground
truth) is read with the ordinary reader and rewritten the way other robots log:

- `write_unitree`: Unitree-like — /joint_states (sensor_msgs/JointState in Unitree's leg
  order FR, FL, RR, RL, plus four foot-sensor entries FL_foot … whose effort is the foot's
  normal force), /imu (sensor_msgs/Imu: the base orientation — or none, a zero quaternion —,
  angular velocity and specific force with IMU noise, frame imu_link), /foot_force
  (std_msgs/Float64MultiArray, normal forces in `feet` order, no header), /effort_command
  (std_msgs/Float64MultiArray, the total torque the joint loop asked for, in Unitree's order);
  no odometry, no contact flags.
- `write_ros2_control`: /joint_states, /imu, /odom (nav_msgs/Odometry whose twist is in the
  WORLD frame, as many estimators publish it), optionally /effort_controller/commands
  (Float64MultiArray); no contact topic.
- every writer takes `storage`: "mcap", "sqlite3" (rosbag2 db3) or "ros1" (a ROS 1 .bag,
  rosbags.rosbag1 with the ROS 1 Noetic types).

The messages are built with rosbags' typestore classes and serialised by rosbags (CDR for
rosbag2, ROS 1 serialisation for .bag), so no rclpy is needed and the ROS 1 bag carries
ROS 1 definitions. The rate is the native log's or a resampling of it (`resample`: linear
interpolation, normalised quaternions, contacts held) — record the native log at
`sensor_rate` 1000 Hz (ciml_sim.recorder) to convert to 500 Hz / 1 kHz without inventing
samples. Each writer returns the matching robot profile (a dict, docs/ROBOT_PROFILE.md);
`write_profile` stores it as YAML.

The command convention (what CIML's reader expects of an effort array): the array stamped
t_{k−1} is the torque that acts over (t_{k−1}, t_k], so the sample at t_k pairs with it —
written here as the native log's u_k (the joint loop's total torque at t_k) at t_{k−1}. That
says when each command acted only if every controller command instant is a sample (the array
then changes where the command did); the diagnosis reads the actuator lag from it (the
samples' phase in the command period, docs/DIAGNOSIS.md). When the samples fall between the
command instants (e.g. 500 Hz from a 1 kHz log without them), a per-sample value cannot say
when the command changed, and u_k is stamped half a sample period before t_k instead: a hold
centred on the sample, which shifts nothing in time on average over the samples' phases
(`command_stamps`).

From the command line (e.g. to try `ciml inspect` on a log in another robot's layout):

    python test/foreign_layouts.py unitree NATIVE_BAG OUT_BAG --robot go1.yaml [--storage mcap|sqlite3|ros1]

NATIVE_BAG: a `ciml record` bag with its /sim/ ground truth (the foot forces come from it);
`--rate HZ` resamples it (`resample`), default: the native rate.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ciml_learning.core.robot import RobotDescription
from ciml_learning.logs import bagio
from ciml_learning.logs.loginputs import load_log

STORAGES = ("mcap", "sqlite3", "ros1")
UNITREE_LEG_ORDER = ("FR", "FL", "RR", "RL")


@dataclass
class NativeLog:
    """A native recording as arrays (robot orders): the reader's SensorLog plus the true
    per-foot normal forces from /sim/contact_forces [N]."""

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    tau: np.ndarray
    u: np.ndarray
    contacts: np.ndarray
    foot_force: np.ndarray
    command_t: np.ndarray | None = None
    """[s] the stamps of the native log's controller commands (/torque_command)."""

    def __len__(self) -> int:
        return len(self.t)


def read_native(robot: RobotDescription, path: str | os.PathLike) -> NativeLog:
    """The native bag through CIML's reader, with the ground-truth foot normal forces."""
    log = load_log(robot, path)
    msgs = bagio.read_messages(path, ["/sim/contact_forces"])["/sim/contact_forces"]
    if not msgs:
        raise ValueError(f"{path}: no /sim/contact_forces (record with ground truth)")
    ts = np.array([s for s, _ in msgs], dtype=np.int64)
    perm = robot.foot_permutation(list(msgs[0][1].foot_names))
    fz = np.array([np.asarray(m.force_z, float)[perm] for _, m in msgs])
    idx = np.clip(np.searchsorted(ts, np.round(log.t * 1e9).astype(np.int64)), 0, len(ts) - 1)
    cmd = bagio.read_messages(path, ["/torque_command"]).get("/torque_command", [])
    return NativeLog(t=log.t, q=log.q, v=log.v, tau=log.tau, u=log.u, contacts=log.contacts, foot_force=fz[idx],
                     command_t=np.array([s for s, _ in cmd], dtype=float) * 1e-9 if cmd else None)


def resample(log: NativeLog, rate_hz: float) -> NativeLog:
    """The log on a uniform grid at `rate_hz` from its first stamp (linear interpolation;
    base quaternion interpolated and normalised; contacts: the latest sample at or before)."""
    t = log.t[0] + np.arange(int(np.floor((log.t[-1] - log.t[0]) * rate_hz + 1e-9)) + 1) / rate_hz

    def lin(x: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, log.t, x[:, j]) for j in range(x.shape[1])], axis=1)

    q = lin(log.q)
    q[:, 3:7] /= np.linalg.norm(q[:, 3:7], axis=1, keepdims=True)
    held = np.clip(np.searchsorted(log.t, t + 1e-9) - 1, 0, len(log.t) - 1)
    return NativeLog(t=t, q=q, v=lin(log.v), tau=lin(log.tau), u=lin(log.u), contacts=log.contacts[held],
                     foot_force=lin(log.foot_force), command_t=log.command_t)


def decimate(log: NativeLog, factor: int) -> NativeLog:
    """Every `factor`-th sample (an exact lower rate of a log whose rate it divides)."""
    return NativeLog(*(getattr(log, f)[::factor] for f in ("t", "q", "v", "tau", "u", "contacts", "foot_force")),
                     command_t=log.command_t)


def command_stamps(log: NativeLog) -> np.ndarray:
    """[s] the stamp of the effort array holding u_k, for k = 1 … N−1 (module docstring): t_{k−1}
    when every command instant inside the log is a sample, else t_k − half a sample period."""
    if log.command_t is not None:
        inside = log.command_t[(log.command_t > log.t[0]) & (log.command_t <= log.t[-1])]
        k = np.clip(np.searchsorted(log.t, inside - 1e-7), 0, len(log.t) - 1)
        if not np.all(np.abs(log.t[k] - inside) < 1e-7):
            return log.t[1:] - 0.5 * np.median(np.diff(log.t))
    return log.t[:-1]


# --- message construction (rosbags typestores) --------------------------------------------------


class _Bag:
    """One output bag in any of STORAGES, written with rosbags' own writers and types."""

    def __init__(self, path: str | os.PathLike, storage: str) -> None:
        from rosbags.typesys import Stores, get_typestore

        if storage not in STORAGES:
            raise ValueError(f"storage {storage!r}; valid: {STORAGES}")
        self.storage = storage
        self.path = Path(path)
        if storage == "ros1":
            from rosbags.rosbag1 import Writer

            self.store = get_typestore(Stores.ROS1_NOETIC)
            self.writer = Writer(self.path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            self.store = get_typestore(Stores.ROS2_JAZZY)
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(self.path, version=9, storage_plugin=plugin)
        self.conns: dict[str, object] = {}
        self.T = self.store.types

    def __enter__(self) -> "_Bag":
        self.writer.open()
        return self

    def __exit__(self, *exc) -> None:
        self.writer.close()

    def header(self, ns: int, frame: str):
        Time = self.T["builtin_interfaces/msg/Time"]
        stamp = Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))
        Header = self.T["std_msgs/msg/Header"]
        if self.storage == "ros1":
            return Header(seq=0, stamp=stamp, frame_id=frame)
        return Header(stamp=stamp, frame_id=frame)

    def write(self, topic: str, msgtype: str, ns: int, msg) -> None:
        conn = self.conns.get(topic)
        if conn is None:
            conn = self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        data = (self.store.serialize_ros1(msg, msgtype) if self.storage == "ros1"
                else self.store.serialize_cdr(msg, msgtype))
        self.writer.write(conn, int(ns), data)

    # message builders
    def joint_state(self, ns: int, names: list[str], pos, vel, eff):
        return self.T["sensor_msgs/msg/JointState"](
            header=self.header(ns, ""), name=list(names), position=np.asarray(pos, float),
            velocity=np.asarray(vel, float), effort=np.asarray(eff, float))

    def float_array(self, values):
        T = self.T
        layout = T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
        return T["std_msgs/msg/Float64MultiArray"](layout=layout, data=np.asarray(values, float))

    def vector3(self, x):
        return self.T["geometry_msgs/msg/Vector3"](x=float(x[0]), y=float(x[1]), z=float(x[2]))

    def imu(self, ns: int, quat_xyzw, gyro, accel, frame: str = "imu_link"):
        """sensor_msgs/Imu; quat_xyzw None: no orientation (a zero quaternion, as drivers that never
        fill it publish)."""
        T = self.T
        quat = np.zeros(4) if quat_xyzw is None else quat_xyzw
        q = T["geometry_msgs/msg/Quaternion"](x=float(quat[0]), y=float(quat[1]), z=float(quat[2]), w=float(quat[3]))
        cov = np.zeros(9)
        return T["sensor_msgs/msg/Imu"](header=self.header(ns, frame), orientation=q, orientation_covariance=cov,
                                        angular_velocity=self.vector3(gyro), angular_velocity_covariance=cov,
                                        linear_acceleration=self.vector3(accel), linear_acceleration_covariance=cov)

    def odometry(self, ns: int, pos, quat_xyzw, lin, ang, frame: str = "odom", child: str = "base_link"):
        T = self.T
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=float(pos[0]), y=float(pos[1]), z=float(pos[2])),
            orientation=T["geometry_msgs/msg/Quaternion"](x=float(quat_xyzw[0]), y=float(quat_xyzw[1]),
                                                          z=float(quat_xyzw[2]), w=float(quat_xyzw[3])))
        twist = T["geometry_msgs/msg/Twist"](linear=self.vector3(lin), angular=self.vector3(ang))
        cov = np.zeros(36)
        return T["nav_msgs/msg/Odometry"](
            header=self.header(ns, frame), child_frame_id=child,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov))


def _rotations(quat_xyzw: np.ndarray) -> np.ndarray:
    import pinocchio as pin

    return np.array([pin.Quaternion(q).matrix() for q in quat_xyzw])


GRAVITY = 9.81  # [m/s²]


def _noisy_imu(log: NativeLog, rng: np.random.Generator, orientation_std: float, gyro_std: float,
               accel_std: float = 0.05, gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)):
    """IMU readings at the base origin: the base orientation tilted by a small random rotation,
    gyro + bias + white noise, and the accelerometer's specific force (REP 145: gravity included)
    f = Rᵀ (a + (0, 0, g)), a the base's world-frame acceleration (the derivative of R v), + white noise."""
    import pinocchio as pin

    quat = np.empty((len(log), 4))
    for k in range(len(log)):
        R = pin.Quaternion(log.q[k, 3:7]).matrix() @ pin.exp3(rng.normal(0.0, orientation_std, 3))
        quat[k] = pin.Quaternion(R).coeffs()
    gyro = log.v[:, 3:6] + np.asarray(gyro_bias) + rng.normal(0.0, gyro_std, (len(log), 3))
    R = _rotations(log.q[:, 3:7])
    a_world = np.gradient(np.einsum("kij,kj->ki", R, log.v[:, :3]), log.t, axis=0)
    accel = np.einsum("kji,kj->ki", R, a_world + [0.0, 0.0, GRAVITY]) + rng.normal(0.0, accel_std, (len(log), 3))
    return quat, gyro, accel


def unitree_joint_order(robot: RobotDescription) -> list[str]:
    """The robot's joints in Unitree's leg order (FR, FL, RR, RL), each leg's joints in model order."""
    legs = {leg: [robot.joint_names[j] for j in joints] for leg, joints in zip(robot.leg_names, robot.leg_joints)}
    return [j for leg in UNITREE_LEG_ORDER for j in legs[leg]]


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def write_unitree(robot: RobotDescription, log: NativeLog, path: str | os.PathLike, storage: str = "mcap",
                  command: bool = True, seed: int = 0, force_noise: float = 1.0,
                  imu_noise: tuple[float, float] = (0.002, 0.005), imu_orientation: bool = True,
                  gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> dict:
    """Unitree-like layout (module docstring); returns its profile. force_noise [N],
    imu_noise (orientation [rad], gyro [rad/s]) standard deviations; imu_orientation False: the
    IMU's quaternion is never filled (zero), as some drivers publish it; gyro_bias [rad/s]."""
    rng = np.random.default_rng(seed)
    order = unitree_joint_order(robot)
    perm = [robot.joint_names.index(j) for j in order]
    feet = list(robot.foot_frames)
    imu_q, imu_w, imu_a = _noisy_imu(log, rng, *imu_noise, gyro_bias=gyro_bias)
    force = np.maximum(log.foot_force + rng.normal(0.0, force_noise, log.foot_force.shape), 0.0)
    cmd_t = command_stamps(log)
    with _Bag(path, storage) as bag:
        for k in range(len(log)):
            ns = _ns(log.t[k])
            js = bag.joint_state(ns, order + feet, np.r_[log.q[k, 7:][perm], np.zeros(len(feet))],
                                 np.r_[log.v[k, 6:][perm], np.zeros(len(feet))], np.r_[log.tau[k][perm], force[k]])
            bag.write("/joint_states", "sensor_msgs/msg/JointState", ns, js)
            bag.write("/imu", "sensor_msgs/msg/Imu", ns,
                      bag.imu(ns, imu_q[k] if imu_orientation else None, imu_w[k], imu_a[k]))
            bag.write("/foot_force", "std_msgs/msg/Float64MultiArray", ns, bag.float_array(force[k]))
            if command and k + 1 < len(log):
                bag.write("/effort_command", "std_msgs/msg/Float64MultiArray", _ns(cmd_t[k]),
                          bag.float_array(log.u[k + 1][perm]))
    inputs = {
        "joint_state": {"topic": "/joint_states", "type": "sensor_msgs/msg/JointState"},
        "imu": {"topic": "/imu", "type": "sensor_msgs/msg/Imu"},
        "base": {"estimate": "imu_legs"},
        "contacts": {"topic": "/foot_force", "type": "std_msgs/msg/Float64MultiArray", "field": "data",
                     "threshold": round(0.15 * robot.total_mass * 9.81, 1),
                     "hysteresis": round(0.1 * robot.total_mass * 9.81, 1)},
    }
    if command:
        inputs["command"] = {"topic": "/effort_command", "type": "std_msgs/msg/Float64MultiArray", "joints": order}
    return _profile(robot, "go1_unitree_layout", inputs, ignore=feet)


def write_ros2_control(robot: RobotDescription, log: NativeLog, path: str | os.PathLike, storage: str = "mcap",
                       command: bool = True, seed: int = 0,
                       imu_noise: tuple[float, float] = (0.002, 0.005)) -> dict:
    """ros2_control-like layout (module docstring); returns its profile."""
    rng = np.random.default_rng(seed)
    names = sorted(robot.joint_names)  # a driver's own order (alphabetical), not the URDF's
    perm = [robot.joint_names.index(j) for j in names]
    imu_q, imu_w, imu_a = _noisy_imu(log, rng, *imu_noise)
    R = _rotations(log.q[:, 3:7])
    lin_world = np.einsum("kij,kj->ki", R, log.v[:, :3])
    ang_world = np.einsum("kij,kj->ki", R, log.v[:, 3:6])
    cmd_t = command_stamps(log)
    with _Bag(path, storage) as bag:
        for k in range(len(log)):
            ns = _ns(log.t[k])
            bag.write("/joint_states", "sensor_msgs/msg/JointState", ns,
                      bag.joint_state(ns, names, log.q[k, 7:][perm], log.v[k, 6:][perm], log.tau[k][perm]))
            bag.write("/imu", "sensor_msgs/msg/Imu", ns, bag.imu(ns, imu_q[k], imu_w[k], imu_a[k]))
            bag.write("/odom", "nav_msgs/msg/Odometry", ns,
                      bag.odometry(ns, log.q[k, :3], log.q[k, 3:7], lin_world[k], ang_world[k]))
            if command and k + 1 < len(log):
                bag.write("/effort_controller/commands", "std_msgs/msg/Float64MultiArray", _ns(cmd_t[k]),
                          bag.float_array(log.u[k + 1][perm]))
    inputs = {
        "joint_state": {"topic": "/joint_states", "type": "sensor_msgs/msg/JointState"},
        "imu": {"topic": "/imu", "type": "sensor_msgs/msg/Imu"},
        "base": {"topic": "/odom", "type": "nav_msgs/msg/Odometry", "twist_frame": "world"},
        "contacts": {"estimate": "dynamics"},
    }
    if command:
        inputs["command"] = {"topic": "/effort_controller/commands", "type": "std_msgs/msg/Float64MultiArray",
                             "joints": names}
    return _profile(robot, "go1_ros2_control_layout", inputs)


def native_profile(robot: RobotDescription) -> dict:
    """CIML's own topics with this robot's URDF and feet."""
    inputs = {
        "joint_state": {"topic": "/joint_states", "type": "sensor_msgs/msg/JointState"},
        "base": {"topic": "/base_state", "type": "nav_msgs/msg/Odometry", "twist_frame": "child"},
        "contacts": {"topic": "/contact_state", "type": "ciml_msgs/msg/ContactState"},
        "command": {"topic": "/torque_command", "type": "ciml_msgs/msg/TorqueCommand"},
    }
    return _profile(robot, "go1_native", inputs)


def _profile(robot: RobotDescription, name: str, inputs: dict, ignore: list[str] | None = None) -> dict:
    from ciml_learning.core.robot import example_robot_data_dir

    urdf = os.path.abspath(robot.urdf_path)
    erd = example_robot_data_dir()
    if urdf.startswith(erd + os.sep):  # portable: a file of example-robot-data
        urdf = "erd:" + os.path.relpath(urdf, erd)
    return {"format": 1, "name": name, "urdf": urdf, "feet": list(robot.foot_frames),
            "joint_map": {}, "ignore_joints": list(ignore or []), "torque_limits": {}, "torque_source": "sensor",
            "inputs": inputs}


def write_profile(profile: dict, path: str | os.PathLike) -> str:
    import yaml

    Path(path).write_text(yaml.safe_dump(profile, sort_keys=False), encoding="utf-8")
    return str(path)


def without_command(profile: dict) -> dict:
    p = dict(profile)
    p["inputs"] = {k: v for k, v in profile["inputs"].items() if k != "command"}
    return p


def main(argv: list[str] | None = None) -> int:
    import argparse

    from ciml_learning.core.profile import load_profile, with_overrides

    ap = argparse.ArgumentParser(description="Rewrite a native CIML recording in another robot's layout.")
    ap.add_argument("layout", choices=("unitree", "ros2_control"))
    ap.add_argument("native_bag")
    ap.add_argument("out_bag")
    ap.add_argument("--robot", help="robot profile of the native bag (URDF, feet; default HyQ)")
    ap.add_argument("--urdf")
    ap.add_argument("--feet", help="A,B,C,D")
    ap.add_argument("--storage", choices=STORAGES, default="mcap")
    ap.add_argument("--no-command", action="store_true", help="leave the command topic out")
    ap.add_argument("--rate", type=float, help="resample to this rate [Hz] (default: the native rate)")
    a = ap.parse_args(argv)
    prof = with_overrides(load_profile(a.robot), a.urdf, a.feet.split(",") if a.feet else None)
    robot = prof.robot()
    log = read_native(robot, a.native_bag)
    if a.rate:
        log = resample(log, a.rate)
    if a.layout == "unitree":
        write_unitree(robot, log, a.out_bag, storage=a.storage, command=not a.no_command)
    else:
        write_ros2_control(robot, log, a.out_bag, storage=a.storage, command=not a.no_command)
    print(f"wrote {a.out_bag} ({a.layout} layout, {a.storage})")
    return 0


__all__ = ["NativeLog", "read_native", "resample", "decimate", "write_unitree", "write_ros2_control",
           "native_profile", "write_profile", "without_command", "unitree_joint_order", "STORAGES"]


if __name__ == "__main__":
    raise SystemExit(main())
