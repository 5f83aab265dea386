"""The robot description: URDF, joint order, feet, limits — defined once, by name.

The robot is a parameter, not a constant: a point-foot quadruped given by a URDF
(floating base, 3 actuated joints per leg) and the names of its foot frames. HyQ
from example-robot-data is the default. Nothing outside this module assumes
HyQ's names or sizes.

Conventions (Pinocchio free-flyer):
- q = [base position (3, world), base orientation quaternion (x, y, z, w), joints (n_j)]
- v = [base linear velocity (3), base angular velocity (3), joints (n_j)], the base
  twist expressed in the base frame.
- Joint order is Pinocchio's (the URDF's tree order); legs are ordered as their
  joints appear, and feet are ordered as their legs, so that the joint block of
  the contact-invariant basis J' is block-diagonal.
"""
from __future__ import annotations

import glob
import os
import sys
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING
from xml.etree import ElementTree

import numpy as np
import pinocchio as pin

from ciml_learning.core.errors import CimlError

if TYPE_CHECKING:
    from ciml_learning.core.batch_dynamics import BatchDynamics

BASE_DOF_NAMES: tuple[str, ...] = ("base_x", "base_y", "base_z", "base_roll", "base_pitch", "base_yaw")
"""Names of the 6 base coordinates of v (linear, then angular; base frame)."""

HYQ_FEET: tuple[str, ...] = ("lf_foot", "lh_foot", "rf_foot", "rh_foot")


class RobotDescriptionError(CimlError):
    """The URDF or the foot names do not describe a supported point-foot robot."""


def urdf_child(element: ElementTree.Element, tag: str) -> ElementTree.Element:
    """The <tag> inside a URDF element, which the URDF format requires there."""
    child = element.find(tag)
    if child is None:
        raise RobotDescriptionError(f"URDF <{element.tag} name={element.get('name')!r}> has no <{tag}>")
    return child


def example_robot_data_dir() -> str:
    """Folder of example-robot-data's robots inside the current environment."""
    candidates = glob.glob(
        os.path.join(sys.prefix, "lib", "python3*", "site-packages", "cmeel.prefix", "share", "example-robot-data",
                     "robots")
    )
    if not candidates:
        raise RobotDescriptionError(
            "example-robot-data not found in this environment; install it (make install) or pass --urdf"
        )
    return candidates[0]


def hyq_urdf_path() -> str:
    return os.path.join(example_robot_data_dir(), "hyq_description", "robots", "hyq_no_sensors.urdf")


MAX_PERMUTATIONS = 64
"""Name orders remembered per robot (a stream whose names change every message is not cached)."""


@dataclass(frozen=True)
class RobotDescription:
    """A floating-base point-foot robot: Pinocchio model plus its names.

    Attributes:
        urdf_path: the URDF the model was built from.
        model: Pinocchio model with a free-flyer root (nq = 7 + n_j, nv = 6 + n_j).
        joint_names: actuated joints, in model order (the order of every joint vector).
        foot_frames: foot frame names, ordered like their legs.
        leg_joints: for each foot, the indices (into joint_names) of its leg's joints.
    """

    urdf_path: str
    model: pin.Model
    joint_names: tuple[str, ...]
    foot_frames: tuple[str, ...]
    leg_joints: tuple[tuple[int, ...], ...]
    foot_frame_ids: tuple[int, ...] = field(repr=False)
    _permutations: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    """Permutations already computed, by names: a 250 Hz stream sends the same names every time."""

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def nv(self) -> int:
        return self.model.nv

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def n_feet(self) -> int:
        return len(self.foot_frames)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("batch", None)  # a handle into the compiled core, rebuilt at first use where it is unpickled
        return state

    @cached_property
    def batch(self) -> "BatchDynamics":
        """The model in the compiled batch core (core.batch_dynamics), built at first use; the model
        is not changed after construction (a modified robot is a new description)."""
        from ciml_learning.core.batch_dynamics import BatchDynamics

        return BatchDynamics(self)

    @cached_property
    def leg_names(self) -> tuple[str, ...]:
        """Short leg names derived from the foot frames ("lf_foot" -> "lf")."""
        return tuple(f[: -len("_foot")] if f.endswith("_foot") else f for f in self.foot_frames)

    @cached_property
    def dof_names(self) -> tuple[str, ...]:
        """Names of the nv generalized velocities (base 6, then joints)."""
        return BASE_DOF_NAMES + self.joint_names

    @cached_property
    def rbd_error_names(self) -> tuple[str, ...]:
        """Names of the contact-invariant error Phi~' entries: base wrench, then 3 per foot.

        The base entries are the generalized forces on the base coordinates (force x, y, z,
        torque about roll, pitch, yaw axes), the foot entries the Cartesian force x, y, z at
        each foot, in the world-aligned frame.
        """
        base = ("base_fx", "base_fy", "base_fz", "base_roll", "base_pitch", "base_yaw")
        feet = tuple(f"foot_{leg}_{ax}" for leg in self.leg_names for ax in "xyz")
        return base + feet

    @cached_property
    def torque_limits(self) -> np.ndarray:
        """Symmetric torque limits per joint [Nm], from the URDF."""
        return np.asarray(self.model.effortLimit[6:], dtype=float).copy()

    @cached_property
    def position_limits(self) -> tuple[np.ndarray, np.ndarray]:
        return (
            np.asarray(self.model.lowerPositionLimit[7:], dtype=float).copy(),
            np.asarray(self.model.upperPositionLimit[7:], dtype=float).copy(),
        )

    @cached_property
    def total_mass(self) -> float:
        return float(sum(inertia.mass for inertia in self.model.inertias))

    @cached_property
    def link_names(self) -> tuple[str, ...]:
        """Body frames that carry inertia (URDF links), in model order."""
        return tuple(
            f.name for f in self.model.frames if f.type == pin.FrameType.BODY and f.name in self.link_inertias
        )

    @cached_property
    def link_inertias(self) -> dict[str, tuple[int, pin.Inertia]]:
        """URDF links with an <inertial>, in URDF order: the index of the joint that moves each and the
        link's own inertia in that joint's frame (Pinocchio merges the links of a joint into
        model.inertias; scaling or identifying one link needs its own)."""
        out = {}
        for link in ElementTree.parse(self.urdf_path).getroot().findall("link"):
            inertial, name = link.find("inertial"), link.attrib["name"]
            if inertial is None or not self.model.existFrame(name):
                continue
            origin = inertial.find("origin")
            placement = origin.attrib if origin is not None else {}
            xyz, rpy = (np.array([float(x) for x in placement.get(k, "0 0 0").split()]) for k in ("xyz", "rpy"))
            mass = float(urdf_child(inertial, "mass").attrib["value"])
            a = urdf_child(inertial, "inertia").attrib
            I_c = np.array([[float(a["ixx"]), float(a["ixy"]), float(a["ixz"])],
                            [float(a["ixy"]), float(a["iyy"]), float(a["iyz"])],
                            [float(a["ixz"]), float(a["iyz"]), float(a["izz"])]])
            R = pin.rpy.rpyToMatrix(*rpy)
            frame = self.model.frames[self.model.getFrameId(name)]
            out[name] = (int(frame.parentJoint), frame.placement.act(pin.Inertia(mass, xyz, R @ I_c @ R.T)))
        return out

    def joint_permutation(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        """Index array p such that values_in_model_order = values[p] for data ordered by `names`.

        Raises RobotDescriptionError naming the missing or unknown joints.
        """
        return self._permutation("joints", names, self._joint_permutation)

    def _permutation(self, kind: str, names, compute) -> np.ndarray:
        key = (kind, tuple(names))
        perm = self._permutations.get(key)
        if perm is None:
            perm = compute(list(names))
            perm.flags.writeable = False  # shared by every caller
            if len(self._permutations) < MAX_PERMUTATIONS:
                self._permutations[key] = perm
        return perm

    def _joint_permutation(self, names: list[str]) -> np.ndarray:
        index = {n: i for i, n in enumerate(names)}
        missing = [j for j in self.joint_names if j not in index]
        unknown = [n for n in names if n not in self.joint_names]
        if missing or unknown or len(names) != len(set(names)):
            raise RobotDescriptionError(
                f"joint names do not match the robot: missing {missing}, unknown {unknown}; "
                f"expected {list(self.joint_names)}"
            )
        return np.array([index[j] for j in self.joint_names], dtype=int)

    def foot_permutation(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        """Like joint_permutation, for foot names (frame names or short leg names accepted)."""
        return self._permutation("feet", names, self._foot_permutation)

    def _foot_permutation(self, names: list[str]) -> np.ndarray:
        canon = [n if n in self.foot_frames else f"{n}_foot" for n in names]
        index = {n: i for i, n in enumerate(canon)}
        missing = [f for f in self.foot_frames if f not in index]
        unknown = [n for n, c in zip(names, canon) if c not in self.foot_frames]
        if missing or unknown or len(canon) != len(set(canon)):
            raise RobotDescriptionError(
                f"foot names do not match the robot: missing {missing}, unknown {unknown}; "
                f"expected {list(self.foot_frames)}"
            )
        return np.array([index[f] for f in self.foot_frames], dtype=int)

    def neutral_configuration(self) -> np.ndarray:
        return pin.neutral(self.model)

    @cached_property
    def standing_joints(self) -> np.ndarray:
        """A crouched standing posture (joint order): each leg's hip flexed and knee bent so
        the foot is under the hip. Derived per leg from the limits: HAA at 0, HFE and KFE at
        ±0.7 / ∓1.4 rad with the signs that keep the knee inside its limits."""
        lo, hi = self.position_limits
        q = np.zeros(self.n_joints)
        for leg in self.leg_joints:
            haa, hfe, kfe = leg
            knee_sign = 1.0 if hi[kfe] > -lo[kfe] else -1.0  # the side the knee can bend to
            q[haa] = np.clip(0.0, lo[haa], hi[haa])
            q[kfe] = np.clip(knee_sign * 1.4, lo[kfe], hi[kfe])
            q[hfe] = np.clip(-knee_sign * 0.7, lo[hfe], hi[hfe])
        return q


def load_robot(urdf_path: str | None = None,
               foot_frames: tuple[str, ...] | list[str] | None = None) -> RobotDescription:
    """Load a point-foot quadruped with a free-flyer root; HyQ by default.

    Each foot's leg is found as the actuated joints on the path from the root to the
    foot frame. Every joint must belong to exactly one leg.
    """
    urdf_path = urdf_path or hyq_urdf_path()
    if not os.path.isfile(urdf_path):
        raise RobotDescriptionError(f"URDF not found: {urdf_path}")
    foot_frames = tuple(foot_frames) if foot_frames is not None else HYQ_FEET
    try:
        model = pin.buildModelFromUrdf(urdf_path, pin.JointModelFreeFlyer())
    except (RuntimeError, ValueError) as err:
        raise RobotDescriptionError(f"cannot load URDF {urdf_path}: {err}") from err
    if model.joints[1].shortname() != "JointModelFreeFlyer":
        raise RobotDescriptionError("the model has no free-flyer root")
    for j in range(2, model.njoints):
        if model.joints[j].nv != 1:
            raise RobotDescriptionError(f"joint {model.names[j]} is not a 1-DoF joint")
    joint_names = tuple(model.names[j] for j in range(2, model.njoints))
    frame_ids = []
    legs = []
    for foot in foot_frames:
        if not model.existFrame(foot):
            bodies = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
            raise RobotDescriptionError(f"foot frame {foot!r} not in the URDF; body frames are {bodies}")
        fid = model.getFrameId(foot)
        frame_ids.append(fid)
        chain = []
        j = model.frames[fid].parentJoint
        while j > 1:
            chain.append(j - 2)  # joint index into joint_names
            j = model.parents[j]
        legs.append(tuple(sorted(chain)))
    flat = sorted(i for leg in legs for i in leg)
    if flat != list(range(len(joint_names))):
        raise RobotDescriptionError(
            f"every actuated joint must belong to exactly one foot's leg; legs {legs} for joints {joint_names}"
        )
    # feet ordered like their legs' joints (block-diagonal joint block of J')
    order = sorted(range(len(foot_frames)), key=lambda k: legs[k][0])
    return RobotDescription(
        urdf_path=urdf_path,
        model=model,
        joint_names=joint_names,
        foot_frames=tuple(foot_frames[k] for k in order),
        leg_joints=tuple(legs[k] for k in order),
        foot_frame_ids=tuple(frame_ids[k] for k in order),
    )
