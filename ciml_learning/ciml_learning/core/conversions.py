"""Message ↔ numpy conversion, by joint and foot name (never by index alone).

Readers accept rclpy messages and rosbags messages alike (same field names).
Writers build rclpy message objects; bags store them CDR-serialised by rclpy, so
live topics and recorded bags carry byte-identical messages.
Every reader rejects non-finite values and wrong names with a ConversionError.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ciml_learning.core.errors import CimlError
from ciml_learning.core.physical_bounds import N_BASE
from ciml_learning.core.robot import RobotDescription


class ConversionError(CimlError):
    """A message cannot be turned into a valid sample (wrong names, sizes or non-finite values)."""


def stamp_to_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def serialized_stamp_ns(data: bytes) -> int:
    """Header stamp [ns] of a serialized message whose first field is a std_msgs/Header, read from the
    CDR bytes without decoding the rest (4-byte encapsulation header, then sec int32, nanosec uint32
    in the byte order it names: 0x00 0x00/0x02 big-endian, 0x00 0x01/0x03 little-endian)."""
    if len(data) < 12:
        raise ConversionError(f"serialized message of {len(data)} bytes has no header stamp")
    little = bool(data[1] & 1)
    sec = int.from_bytes(data[4:8], "little" if little else "big", signed=True)
    return sec * 1_000_000_000 + int.from_bytes(data[8:12], "little" if little else "big")


def stamp_msg(ns: int):
    from builtin_interfaces.msg import Time

    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def header_msg(ns: int, frame_id: str = ""):
    from std_msgs.msg import Header

    return Header(stamp=stamp_msg(ns), frame_id=frame_id)


def check_finite(name: str, *arrays: np.ndarray) -> None:
    """ConversionError "<name>: non-finite value" unless every entry of every array is finite."""
    for a in arrays:
        if a.size and not np.all(np.isfinite(a)):
            raise ConversionError(f"{name}: non-finite value")


def _vector(values, n: int, what: str) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if a.shape != (n,):
        raise ConversionError(f"{what}: expected {n} values, got {a.size}")
    return a


def commanded_torque(
    feedforward: np.ndarray,
    feedback_linearization: np.ndarray,
    position_target: np.ndarray,
    velocity_target: np.ndarray,
    stiffness: np.ndarray,
    damping: np.ndarray,
    q_measured: np.ndarray,
    qd_measured: np.ndarray,
    limits: np.ndarray,
    elapsed: float = 0.0,
) -> np.ndarray:
    """Total joint torque command u of the low-level joint loop [Nm] (TorqueCommand.msg).

    u = u_ff + u_fb,lin + K_p (q_target + q̇_target·Δ − q) + K_d (q̇_target − q̇), clipped
    to ±limits, where Δ = `elapsed` [s] is the time since the command's header stamp:
    between commands the joint loop follows the position target along the velocity
    target.

    This is the joint-loop law's one definition (the specification). The learning side
    (Γ = τ − u, eq. 14: loginputs, the state_filter node) calls it. The plant's 1 kHz loop
    runs a compiled copy for speed (ciml_sim.joint_loop.command_coefficients and
    actuation: the same u in coefficient form c − K_p q − K_d q̇ + ċ Δ, then the
    actuator effects); ciml_sim/test/test_joint_loop_law.py asserts the compiled u equals
    this function on random inputs.
    """
    u = (
        feedforward
        + feedback_linearization
        + stiffness * (position_target + velocity_target * elapsed - q_measured)
        + damping * (velocity_target - qd_measured)
    )
    return np.clip(u, -limits, limits)


# --- sensor_msgs/JointState -------------------------------------------------------


def joint_state_msg(robot: RobotDescription, stamp_ns: int, q: np.ndarray, qd: np.ndarray, tau: np.ndarray):
    from sensor_msgs.msg import JointState

    return JointState(
        header=header_msg(stamp_ns),
        name=list(robot.joint_names),
        position=q.tolist(),
        velocity=qd.tolist(),
        effort=tau.tolist(),
    )


def joint_state_arrays(robot: RobotDescription, msg) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, q̇, τ_measured) in the robot's joint order."""
    perm = robot.joint_permutation(list(msg.name))
    n = len(msg.name)
    q = _vector(msg.position, n, "joint_states.position")[perm]
    qd = _vector(msg.velocity, n, "joint_states.velocity")[perm]
    tau = _vector(msg.effort, n, "joint_states.effort")[perm]
    check_finite("joint_states", q, qd, tau)
    return q, qd, tau


# --- nav_msgs/Odometry (base) ------------------------------------------------------


def odometry_msg(stamp_ns: int, position: np.ndarray, quaternion_xyzw: np.ndarray, linear: np.ndarray,
                 angular: np.ndarray):
    """Base state; twist in the base frame (child_frame_id), as nav_msgs/Odometry defines."""
    from geometry_msgs.msg import Point, Pose, PoseWithCovariance, Quaternion, Twist, TwistWithCovariance, Vector3
    from nav_msgs.msg import Odometry

    x, y, z, w = (float(c) for c in quaternion_xyzw)
    return Odometry(
        header=header_msg(stamp_ns, "world"),
        child_frame_id="base",
        pose=PoseWithCovariance(
            pose=Pose(position=Point(x=float(position[0]), y=float(position[1]), z=float(position[2])),
                      orientation=Quaternion(x=x, y=y, z=z, w=w))
        ),
        twist=TwistWithCovariance(
            twist=Twist(linear=Vector3(x=float(linear[0]), y=float(linear[1]), z=float(linear[2])),
                        angular=Vector3(x=float(angular[0]), y=float(angular[1]), z=float(angular[2])))
        ),
    )


def odometry_arrays(msg) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(base position (3), quaternion xyzw (4, normalised), base twist [linear, angular] (6))."""
    p = msg.pose.pose.position
    o = msg.pose.pose.orientation
    t = msg.twist.twist
    pos = np.array([p.x, p.y, p.z], dtype=float)
    quat = np.array([o.x, o.y, o.z, o.w], dtype=float)
    twist = np.array([t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z], dtype=float)
    check_finite("base_state", pos, quat, twist)
    norm = np.linalg.norm(quat)
    if not 0.9 < norm < 1.1:
        raise ConversionError(f"base_state: orientation quaternion has norm {norm:.3f}, expected 1")
    return pos, quat / norm, twist


# --- ciml_msgs/ContactState --------------------------------------------------------


def contact_state_msg(robot: RobotDescription, stamp_ns: int, contacts: np.ndarray):
    from ciml_msgs.msg import ContactState

    return ContactState(header=header_msg(stamp_ns), foot_names=list(robot.foot_frames),
                        in_contact=[bool(c) for c in contacts])


def contact_state_arrays(robot: RobotDescription, msg) -> np.ndarray:
    names = list(msg.foot_names)
    flags = np.asarray(msg.in_contact, dtype=bool)
    if flags.shape != (len(names),):
        raise ConversionError(f"contact_state: {len(names)} foot names but {flags.size} flags")
    return flags[robot.foot_permutation(names)]


# --- ciml_msgs/TorqueCommand -------------------------------------------------------


@dataclass
class TorqueCommandArrays:
    """TorqueCommand content in the robot's joint order."""

    mode: int
    feedforward: np.ndarray
    feedback_linearization: np.ndarray
    position_target: np.ndarray
    velocity_target: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray

    def total(self, q: np.ndarray, qd: np.ndarray, limits: np.ndarray, elapsed: float = 0.0) -> np.ndarray:
        """Joint-loop torque u at `elapsed` seconds after the command's stamp (commanded_torque)."""
        return commanded_torque(self.feedforward, self.feedback_linearization, self.position_target,
                                self.velocity_target, self.stiffness, self.damping, q, qd, limits, elapsed)


def torque_command_msg(robot: RobotDescription, stamp_ns: int, cmd: TorqueCommandArrays):
    from ciml_msgs.msg import TorqueCommand

    return TorqueCommand(
        header=header_msg(stamp_ns),
        mode=int(cmd.mode),
        joint_names=list(robot.joint_names),
        feedforward=cmd.feedforward.tolist(),
        feedback_linearization=cmd.feedback_linearization.tolist(),
        position_target=cmd.position_target.tolist(),
        velocity_target=cmd.velocity_target.tolist(),
        stiffness=cmd.stiffness.tolist(),
        damping=cmd.damping.tolist(),
    )


TORQUE_COMMAND_FIELDS = ("feedforward", "feedback_linearization", "position_target", "velocity_target", "stiffness",
                         "damping")
"""The per-joint arrays of ciml_msgs/TorqueCommand, in TorqueCommandArrays' order after its mode."""


def torque_command_arrays(robot: RobotDescription, msg) -> TorqueCommandArrays:
    perm = robot.joint_permutation(msg.joint_names)
    # one (6, n) array: one permutation and one finiteness check instead of six (250 Hz, two readers)
    n = len(perm)
    rows = np.stack([_vector(getattr(msg, f), n, f"torque_command.{f}") for f in TORQUE_COMMAND_FIELDS])[:, perm]
    check_finite("torque_command", rows)
    if np.any(rows[4:] < 0):
        raise ConversionError("torque_command: negative stiffness or damping")
    return TorqueCommandArrays(int(msg.mode), *rows)


# --- ciml_msgs/ModelError ----------------------------------------------------------


def model_error_msg(
    robot: RobotDescription,
    stamp_ns: int,
    source: str,
    rbd_error: np.ndarray,
    rbd_observed: np.ndarray,
    actuation_error: np.ndarray,
    actuation_observed: np.ndarray,
    rbd_variance: np.ndarray | None = None,
    actuation_variance: np.ndarray | None = None,
    generalized_variance: np.ndarray | None = None,
):
    """generalized_variance: Φ̃'s predictive variance (nv: the base wrench in robot.rbd_error_names
    order, then robot.joint_names), if known."""
    from ciml_msgs.msg import ModelError

    nr, na = len(robot.rbd_error_names), robot.n_joints
    return ModelError(
        header=header_msg(stamp_ns),
        source=source,
        rbd_names=list(robot.rbd_error_names),
        rbd_error=np.asarray(rbd_error, float).tolist(),
        rbd_observed=[bool(b) for b in rbd_observed],
        rbd_variance=(np.zeros(nr) if rbd_variance is None else np.asarray(rbd_variance, float)).tolist(),
        actuation_names=list(robot.joint_names),
        actuation_error=np.asarray(actuation_error, float).tolist(),
        actuation_observed=[bool(b) for b in actuation_observed],
        actuation_variance=(np.zeros(na) if actuation_variance is None
                            else np.asarray(actuation_variance, float)).tolist(),
        generalized_variance=[] if generalized_variance is None else np.asarray(generalized_variance, float).tolist(),
    )


def _by_name(names, expected, what: str) -> np.ndarray:
    """Index array p with values_in_expected_order = values[p] for values ordered by `names`.

    `names` must hold each of `expected` exactly once and nothing else (ConversionError)."""
    names, expected = list(names), list(expected)
    index = {n: i for i, n in enumerate(names)}
    missing = [n for n in expected if n not in index]
    unknown = [n for n in names if n not in expected]
    if missing or unknown or len(index) != len(names):
        repeated = sorted({n for n in names if names.count(n) > 1})
        raise ConversionError(f"{what} names {names} do not match the robot's {expected}: missing {missing}, "
                              f"unknown {unknown}, repeated {repeated}")
    return np.array([index[n] for n in expected], dtype=int)


@dataclass
class ModelErrorArrays:
    """ModelError content in the robot's orders: Φ̃' (eq. 11) in robot.rbd_error_names order,
    Γ (eq. 14) in robot.joint_names order, each with its observed mask and variance."""

    source: str
    rbd_error: np.ndarray
    rbd_observed: np.ndarray
    rbd_variance: np.ndarray
    actuation_error: np.ndarray
    actuation_observed: np.ndarray
    actuation_variance: np.ndarray
    generalized_variance: np.ndarray | None = None  # Φ̃'s (nv: base wrench, then joints), if sent


def _variance(values, perm: np.ndarray, what: str) -> np.ndarray:
    n = len(perm)
    if len(values) == 0:  # not sent: nothing known about the confidence
        return np.full(n, np.inf)
    v = np.asarray(values, dtype=float)
    if v.shape != (n,) or not np.all(np.isfinite(v)) or np.any(v < 0):
        raise ConversionError(f"model_error: {what} must be {n} finite values ≥ 0")
    return v[perm]


def model_error_arrays(robot: RobotDescription, msg) -> ModelErrorArrays:
    """A ciml_msgs/ModelError in the robot's orders: the one decoder of the message.

    Entries are matched by name (each of robot.rbd_error_names and robot.joint_names
    exactly once). Wrong, missing or repeated names, wrong sizes of values or observed
    masks, non-finite errors and non-finite or negative variances raise ConversionError.
    An empty variance array (not sent) decodes as infinite: nothing is known about the
    confidence (the controller's trust gate then rejects the prediction); an empty
    generalized_variance as None (the gate then compares Φ̃' with its mapped prior).
    """
    perm_r = _by_name(msg.rbd_names, robot.rbd_error_names, "model_error: rbd")
    perm_a = _by_name(msg.actuation_names, robot.joint_names, "model_error: joint")
    nr, nj = len(perm_r), len(perm_a)
    phi = _vector(msg.rbd_error, nr, "model_error.rbd_error")[perm_r]
    gamma = _vector(msg.actuation_error, nj, "model_error.actuation_error")[perm_a]
    obs_r = np.asarray(msg.rbd_observed, dtype=bool)
    obs_a = np.asarray(msg.actuation_observed, dtype=bool)
    if obs_r.shape != (nr,) or obs_a.shape != (nj,):
        raise ConversionError(f"model_error: observed masks have {obs_r.size} and {obs_a.size} entries, "
                              f"expected {nr} and {nj}")
    check_finite("model_error", phi, gamma)
    generalized = None
    if len(getattr(msg, "generalized_variance", ())):  # absent from a log recorded with the older definition
        base = set(robot.rbd_error_names[:N_BASE])
        perm_b = _by_name([n for n in msg.rbd_names if n in base], robot.rbd_error_names[:N_BASE], "model_error: base")
        generalized = _variance(msg.generalized_variance, np.concatenate([perm_b, N_BASE + perm_a]),
                                "generalized_variance")
    return ModelErrorArrays(
        source=str(msg.source),
        rbd_error=phi, rbd_observed=obs_r[perm_r], rbd_variance=_variance(msg.rbd_variance, perm_r, "rbd_variance"),
        actuation_error=gamma, actuation_observed=obs_a[perm_a],
        actuation_variance=_variance(msg.actuation_variance, perm_a, "actuation_variance"),
        generalized_variance=generalized,
    )


# --- ciml_msgs/RobotState (filtered state) ------------------------------------------


def _pose(position: np.ndarray, quat: np.ndarray):
    from geometry_msgs.msg import Point, Pose, Quaternion

    return Pose(position=Point(x=float(position[0]), y=float(position[1]), z=float(position[2])),
                orientation=Quaternion(x=float(quat[0]), y=float(quat[1]), z=float(quat[2]), w=float(quat[3])))


def _twist(six: np.ndarray, accel: bool = False):
    from geometry_msgs.msg import Accel, Twist, Vector3

    lin = Vector3(x=float(six[0]), y=float(six[1]), z=float(six[2]))
    ang = Vector3(x=float(six[3]), y=float(six[4]), z=float(six[5]))
    return Accel(linear=lin, angular=ang) if accel else Twist(linear=lin, angular=ang)


def _six(msg) -> np.ndarray:
    return np.array([msg.linear.x, msg.linear.y, msg.linear.z, msg.angular.x, msg.angular.y, msg.angular.z], float)


def robot_state_msg(robot: RobotDescription, stamp_ns: int, q: np.ndarray, v: np.ndarray, a: np.ndarray,
                    tau: np.ndarray, tau_dot: np.ndarray, u: np.ndarray, contacts: np.ndarray, valid: bool,
                    effort_valid: bool | None = None):
    """Filtered full state (Pinocchio q, v, q̈; τ, τ̇, u) as ciml_msgs/RobotState (effort_valid
    None: valid)."""
    from ciml_msgs.msg import RobotState

    return RobotState(
        header=header_msg(stamp_ns, "world"), joint_names=list(robot.joint_names),
        base_pose=_pose(q[:3], q[3:7]), base_twist=_twist(v[:6]), base_acceleration=_twist(a[:6], accel=True),
        position=q[7:].tolist(), velocity=v[6:].tolist(), acceleration=a[6:].tolist(),
        effort_measured=np.asarray(tau, float).tolist(), effort_rate=np.asarray(tau_dot, float).tolist(),
        effort_commanded=np.asarray(u, float).tolist(),
        foot_names=list(robot.foot_frames), in_contact=[bool(c) for c in contacts], valid=bool(valid),
        effort_valid=bool(valid if effort_valid is None else effort_valid))


def robot_state_arrays(robot: RobotDescription, msg) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                              np.ndarray, np.ndarray, np.ndarray, bool, bool]:
    """(q, v, q̈, τ, τ̇, u, contacts, valid, effort_valid) in the robot's orders from a RobotState."""
    perm = robot.joint_permutation(list(msg.joint_names))
    n = len(msg.joint_names)
    p, o = msg.base_pose.position, msg.base_pose.orientation
    q = np.concatenate([[p.x, p.y, p.z], [o.x, o.y, o.z, o.w], _vector(msg.position, n, "position")[perm]])
    v = np.concatenate([_six(msg.base_twist), _vector(msg.velocity, n, "velocity")[perm]])
    a = np.concatenate([_six(msg.base_acceleration), _vector(msg.acceleration, n, "acceleration")[perm]])
    tau = _vector(msg.effort_measured, n, "effort_measured")[perm]
    tau_dot = _vector(msg.effort_rate, n, "effort_rate")[perm]
    u = _vector(msg.effort_commanded, n, "effort_commanded")[perm]
    check_finite("filtered_state", q, v, a, tau, tau_dot, u)
    flags = np.asarray(msg.in_contact, dtype=bool)
    if flags.shape != (len(msg.foot_names),):
        raise ConversionError("filtered_state: foot names and contact flags differ in length")
    return (q, v, a, tau, tau_dot, u, flags[robot.foot_permutation(list(msg.foot_names))], bool(msg.valid),
            bool(msg.effort_valid))


# --- ciml_msgs/RobotReference (read side, for the model server) ----------------------


def robot_reference_arrays(robot: RobotDescription, msg) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(qᵈ (nq), q̇ᵈ (nv), q̈ᵈ (nv), contact schedule (n_feet)) of a RobotReference, robot order.

    Base twist/acceleration stay in the base frame (Pinocchio free-flyer convention);
    the quaternion is normalised. Wrong names, sizes or non-finite values are a
    ConversionError. (ciml_control.conversions.reference_point is the controller's
    reader; this one returns plain arrays so ciml_learning does not import ciml_control.)
    """
    perm = robot.joint_permutation(list(msg.joint_names))
    n = len(msg.joint_names)
    p, o = msg.base_pose.position, msg.base_pose.orientation
    quat = np.array([o.x, o.y, o.z, o.w], dtype=float)
    q = np.concatenate([[p.x, p.y, p.z], quat, _vector(msg.position, n, "reference.position")[perm]])
    v = np.concatenate([_six(msg.base_twist), _vector(msg.velocity, n, "reference.velocity")[perm]])
    a = np.concatenate([_six(msg.base_acceleration), _vector(msg.acceleration, n, "reference.acceleration")[perm]])
    check_finite("reference", q, v, a)
    norm = np.linalg.norm(quat)
    if not 0.9 < norm < 1.1:
        raise ConversionError(f"reference: orientation quaternion has norm {norm:.3f}, expected 1")
    q[3:7] /= norm
    flags = np.asarray(msg.in_contact, dtype=bool)
    if flags.shape != (len(msg.foot_names),):
        raise ConversionError("reference: foot names and contact flags differ in length")
    return q, v, a, flags[robot.foot_permutation(list(msg.foot_names))]
