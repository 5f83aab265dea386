"""`state_publisher`: the robot for 3D views (what robot_state_publisher does; no wheel of it
exists here). Publishes
- /robot_description (std_msgs/String, transient local): the URDF text,
- /tf_static: the URDF's fixed joints (transient local),
- /tf: odom → base link from /base_state, and parent → child link of every actuated joint
  from /joint_states (forward kinematics: ciml_learning.core.tf_tree, Pinocchio),
at most `publish_rate` times per second each, stamped with the sample's own stamp.
"""
from __future__ import annotations

from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.profile import load_profile
from ciml_learning.core.tf_tree import LinkTransform, LinkTree
from ciml_learning.ros.node_params import STATE_PUBLISHER
from ciml_learning.ros.ros_common import LATCHED_QOS, SENSOR_QOS, Health, declare_schema, run_node

TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
"""tf2's TransformBroadcaster profile."""


def _transform_msg(stamp, t: LinkTransform) -> TransformStamped:
    x, y, z = (float(c) for c in t.translation)
    qx, qy, qz, qw = (float(c) for c in t.quaternion_xyzw)
    msg = TransformStamped(child_frame_id=t.child,
                           transform=Transform(translation=Vector3(x=x, y=y, z=z),
                                               rotation=Quaternion(x=qx, y=qy, z=qz, w=qw)))
    msg.header.stamp = stamp
    msg.header.frame_id = t.parent
    return msg


class StatePublisherNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("state_publisher", **kwargs)
        p = declare_schema(self, STATE_PUBLISHER, self.apply)
        self.min_period_ns = int(1e9 / p["publish_rate"])
        self.odom_frame = p["odom_frame"]
        self.robot = load_profile(p["robot"]).robot()
        self.tree = LinkTree(self.robot)
        self.health = Health(self)
        self.pub_tf = self.create_publisher(TFMessage, topics.TF, TF_QOS)
        self.pub_static = self.create_publisher(TFMessage, topics.TF_STATIC, LATCHED_QOS)
        self.pub_description = self.create_publisher(String, topics.ROBOT_DESCRIPTION, LATCHED_QOS)
        with open(self.robot.urdf_path, encoding="utf-8") as f:
            self.pub_description.publish(String(data=f.read()))
        now = self.get_clock().now().to_msg()
        self.pub_static.publish(TFMessage(transforms=[_transform_msg(now, t) for t in self.tree.fixed_transforms()]))
        self._last_ns = {"joints": -(2**62), "base": -(2**62)}
        self.create_subscription(JointState, topics.JOINT_STATES, self.on_joints, SENSOR_QOS)
        self.create_subscription(Odometry, topics.BASE_STATE, self.on_base, SENSOR_QOS)

    def apply(self, changes: dict) -> str | None:
        if "publish_rate" in changes:
            self.min_period_ns = int(1e9 / changes["publish_rate"])
        return None

    def _due(self, key: str, stamp_ns: int) -> bool:
        # a stamp going back (a simulation reset, a replayed bag) restarts the throttle
        if stamp_ns - self._last_ns[key] < self.min_period_ns and stamp_ns >= self._last_ns[key]:
            return False
        self._last_ns[key] = stamp_ns
        return True

    def on_joints(self, msg: JointState) -> None:
        if not self._due("joints", cv.stamp_to_ns(msg.header.stamp)):
            return
        try:
            q, _, _ = cv.joint_state_arrays(self.robot, msg)
            transforms = self.tree.moving_transforms(q)
        except CimlError as err:
            self.health.count("rejected_joint_states", f"joint_states rejected: {err}")
            return
        self.pub_tf.publish(TFMessage(transforms=[_transform_msg(msg.header.stamp, t) for t in transforms]))
        self.health.counts["tf_published"] += 1

    def on_base(self, msg: Odometry) -> None:
        if not self._due("base", cv.stamp_to_ns(msg.header.stamp)):
            return
        try:
            position, quaternion, _ = cv.odometry_arrays(msg)
        except CimlError as err:
            self.health.count("rejected_base_states", f"base_state rejected: {err}")
            return
        parent = self.odom_frame or msg.header.frame_id or "odom"
        t = LinkTransform(parent, self.tree.root_link, position, quaternion)
        self.pub_tf.publish(TFMessage(transforms=[_transform_msg(msg.header.stamp, t)]))


def main(args=None) -> None:
    run_node(StatePublisherNode, args)
if __name__ == "__main__":
    main()
