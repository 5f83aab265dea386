"""ciml_msgs/RobotReference ↔ numpy for the controller, by joint/foot name (ModelError:
ciml_learning.core.conversions.model_error_arrays).

Like ciml_learning.core.conversions: readers accept rclpy and rosbags messages, reject
wrong names and non-finite values with a ConversionError; writers build rclpy messages.
"""
from __future__ import annotations

import numpy as np

from ciml_learning.core.conversions import check_finite, header_msg, robot_reference_arrays, stamp_to_ns
from ciml_learning.core.profile import ProfileError, RobotProfile
from ciml_learning.core.robot import RobotDescription

from .references import ReferencePoint


def reference_msg(robot: RobotDescription, stamp_ns: int, ref: ReferencePoint):
    """A ReferencePoint as ciml_msgs/RobotReference (base twist/acceleration in the base frame)."""
    from ciml_msgs.msg import RobotReference
    from geometry_msgs.msg import Accel, Point, Pose, Quaternion, Twist, Vector3

    q, v, a = (np.asarray(x, float) for x in (ref.q, ref.v, ref.a))

    def vec(x):
        return Vector3(x=float(x[0]), y=float(x[1]), z=float(x[2]))

    return RobotReference(
        header=header_msg(stamp_ns, "world"),
        motion=str(ref.motion),
        phase=float(ref.phase),
        joint_names=list(robot.joint_names),
        base_pose=Pose(position=Point(x=float(q[0]), y=float(q[1]), z=float(q[2])),
                       orientation=Quaternion(x=float(q[3]), y=float(q[4]), z=float(q[5]), w=float(q[6]))),
        base_twist=Twist(linear=vec(v[:3]), angular=vec(v[3:6])),
        base_acceleration=Accel(linear=vec(a[:3]), angular=vec(a[3:6])),
        position=q[7:].tolist(),
        velocity=v[6:].tolist(),
        acceleration=a[6:].tolist(),
        foot_names=list(robot.foot_frames),
        in_contact=[bool(c) for c in ref.contacts],
    )


def reference_point(robot: RobotDescription, msg) -> ReferencePoint:
    """RobotReference → ReferencePoint in the robot's joint and foot order (t = header stamp [s])."""
    q, v, a, contacts = robot_reference_arrays(robot, msg)
    check_finite("reference.phase", np.array([msg.phase], float))
    return ReferencePoint(t=stamp_to_ns(msg.header.stamp) * 1e-9, q=q, v=v, a=a, contacts=contacts,
                          phase=float(msg.phase), motion=str(msg.motion))


# --- commands for a robot's own controllers -------------------------------------------------

FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"


def effort_joint_order(profile: RobotProfile, robot: RobotDescription) -> np.ndarray:
    """Indices into the robot's joint order, in the order of the profile's effort array: the
    `joints` of its command role when that is a std_msgs/Float64MultiArray (a ros2_control effort
    forward_command_controller's `commands`, e.g. solo12.yaml), else the robot's own joint order.
    A list that misses, repeats or does not know a joint is a ProfileError (one line)."""
    spec = profile.inputs.get("command") or {}
    if spec.get("type") != FLOAT64_ARRAY:
        return np.arange(robot.n_joints)
    names = [profile.to_urdf_name(j) for j in spec.get("joints", ())]
    if sorted(names) != sorted(robot.joint_names):
        raise ProfileError(f"profile {profile.path or profile.name}: inputs.command.joints {list(names)} must name "
                           f"each joint of the robot once: {list(robot.joint_names)}")
    return np.array([robot.joint_names.index(j) for j in names], dtype=int)


def effort_array_msg(effort: np.ndarray, order: np.ndarray):
    """Joint torques [Nm] (robot joint order) as std_msgs/Float64MultiArray in `order`
    (effort_joint_order): what an effort forward_command_controller takes. Headerless: it
    acts when it arrives."""
    from std_msgs.msg import Float64MultiArray

    return Float64MultiArray(data=np.asarray(effort, float)[order].tolist())


def feedforward_msg(robot: RobotDescription, stamp_ns: int, effort: np.ndarray):
    """The learned joint-torque correction [Nm] as sensor_msgs/JointState (`name`, `effort`;
    position and velocity empty), stamped with the joint sample it was computed for."""
    from sensor_msgs.msg import JointState

    return JointState(header=header_msg(stamp_ns), name=list(robot.joint_names),
                      effort=np.asarray(effort, float).tolist())
