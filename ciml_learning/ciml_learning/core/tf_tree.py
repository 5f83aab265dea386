"""The robot's link tree as /tf transforms (what robot_state_publisher computes), from the
URDF's joints and Pinocchio's forward kinematics on the RobotDescription.

Every URDF joint is one transform parent link → child link; fixed joints are constant
(/tf_static), actuated joints move with the joint angles (/tf). The base pose itself
(odom → root link) comes from the base state, not from here. No rclpy: the node
(nodes/state_publisher.py) only converts these to TransformStamped messages.
"""
from __future__ import annotations

from dataclasses import dataclass
from xml.etree import ElementTree

import numpy as np
import pinocchio as pin

from ciml_learning.core.robot import RobotDescription, RobotDescriptionError, urdf_child


@dataclass(frozen=True)
class LinkTransform:
    """Pose of `child` in `parent`: translation [m] and unit quaternion (x, y, z, w)."""

    parent: str
    child: str
    translation: np.ndarray
    quaternion_xyzw: np.ndarray


@dataclass(frozen=True)
class _Edge:
    parent: str
    child: str
    fixed: bool
    parent_frame: int
    child_frame: int


class LinkTree:
    """Parent → child transforms of every URDF joint of `robot`."""

    def __init__(self, robot: RobotDescription) -> None:
        self.robot = robot
        model = robot.model
        self._data = model.createData()
        root = ElementTree.parse(robot.urdf_path).getroot()
        edges = []
        for joint in root.findall("joint"):
            parent, child = (urdf_child(joint, tag).attrib["link"] for tag in ("parent", "child"))
            ids = []
            for link in (parent, child):
                if not model.existFrame(link, pin.FrameType.BODY):
                    raise RobotDescriptionError(f"URDF link {link!r} has no body frame in the model")
                ids.append(model.getFrameId(link, pin.FrameType.BODY))
            edges.append(_Edge(parent, child, joint.get("type") == "fixed", ids[0], ids[1]))
        self._edges = tuple(edges)
        children = {e.child for e in edges}
        roots = [link.attrib["name"] for link in root.findall("link") if link.attrib["name"] not in children]
        if len(roots) != 1:
            raise RobotDescriptionError(f"the URDF's link tree must have one root link, found {roots}")
        self.root_link: str = roots[0]
        """The link the free-flyer moves (the base pose of /base_state is this link's)."""

    def _placements(self, q_joints: np.ndarray) -> list[pin.SE3]:
        """Frame placements with the base at the origin (joint angles in model order)."""
        q = self.robot.neutral_configuration()
        q[:7] = (0, 0, 0, 0, 0, 0, 1)
        q[7:] = q_joints
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        return self._data.oMf

    def _transforms(self, q_joints: np.ndarray, fixed: bool) -> list[LinkTransform]:
        oMf = self._placements(q_joints)
        out = []
        for e in self._edges:
            if e.fixed != fixed:
                continue
            T = oMf[e.parent_frame].actInv(oMf[e.child_frame])
            out.append(LinkTransform(e.parent, e.child, T.translation.copy(), pin.SE3ToXYZQUAT(T)[3:].copy()))
        return out

    def fixed_transforms(self) -> list[LinkTransform]:
        """Transforms of the fixed joints (constant: /tf_static)."""
        return self._transforms(self.robot.neutral_configuration()[7:], fixed=True)

    def moving_transforms(self, q_joints: np.ndarray) -> list[LinkTransform]:
        """Transforms of the actuated joints at joint angles `q_joints` (model order) [rad]."""
        q_joints = np.asarray(q_joints, dtype=float)
        if q_joints.shape != (self.robot.n_joints,) or not np.all(np.isfinite(q_joints)):
            raise RobotDescriptionError(f"joint angles must be {self.robot.n_joints} finite values")
        return self._transforms(q_joints, fixed=False)
