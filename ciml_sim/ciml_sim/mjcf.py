"""The MuJoCo model of the robot, generated from the Pinocchio model of its URDF.

Same kinematic tree, joint placements and axes, joint order, masses, CoMs and
inertias (Pinocchio's body inertias, which already merge fixed links such as the
feet and the IMU into their parent body), joint limits. Deliberate differences from
the URDF (ciml_sim/README.md lists each with its reason): primitive geoms instead of
.dae meshes, of which only small foot spheres and a trunk box collide; soft contacts;
no URDF joint damping (the nominal model has none; friction is a scenario effect).

Free-joint conventions
    MuJoCo:    qpos = [p, quat (w, x, y, z), joints]
               qvel = [ṗ in the world frame, ω in the body frame, joints]
    Pinocchio: q    = [p, quat (x, y, z, w), joints]
               v    = [Rᵀṗ, ω, joints]   (base twist in the base frame)
so qvel = T v with T = blockdiag(R, I). Generalized forces map by the transpose
(equal power): f_pin = Tᵀ f_mj; accelerations by qacc = T v̇ + Ṫ v with
Ṫ v = [R (ω × Rᵀṗ), 0].
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from ciml_learning.core.dynamics import quaternion_xyzw
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription

FOOT_RADIUS = 0.002
"""Collision radius of the feet [m]. The nominal model has point feet at the URDF foot
frames; a sphere of radius r puts the contact point r below the frame and adds a moment
r × f_tangential on the lower leg that the nominal model lacks. HyQ's URDF sphere is
21.75 mm; 2 mm keeps that moment below 0.1 Nm per 50 N of tangential force."""
FOOT_FRICTION = 1.0
"""Foot–floor Coulomb friction coefficient (the controller assumes a cone of 0.5)."""
CONTACT_SOLREF = (0.005, 1.0)
"""Contact time constant [s] and damping ratio: stiff, critically damped (≥ 2 physics steps)."""
CONTACT_SOLIMP = (0.95, 0.99, 0.001)
IMPRATIO = 100.0
"""Frictional-to-normal impedance ratio (elliptic cones): soft contacts otherwise let a foot
under a steady tangential load creep (~2 mm/s with HyQ standing); at 100 it stays put."""
TIMESTEP = 0.001
"""Physics step [s] (1 kHz, HyQ's joint-loop rate)."""


class MjcfError(CimlError):
    """The robot description cannot be turned into a MuJoCo model."""


def _fmt(values) -> str:
    return " ".join(f"{float(v):.17g}" for v in np.ravel(values))


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    c = quaternion_xyzw(R)  # x y z w
    return np.array([c[3], c[0], c[1], c[2]])


def _inertial(inertia: pin.Inertia) -> str:
    I = inertia.inertia
    full = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
    mass = max(inertia.mass, 1e-9)
    return f'<inertial pos="{_fmt(inertia.lever)}" mass="{mass:.17g}" fullinertia="{_fmt(full)}"/>'


def _joint_axis(jm, name: str) -> np.ndarray:
    short = jm.shortname()
    axes = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0)}
    if short in axes:
        return np.array(axes[short])
    if short == "JointModelRevoluteUnaligned":
        return np.asarray(jm.axis, dtype=float)
    raise MjcfError(f"joint {name}: type {short} is not supported (revolute joints with limits only)")


def build_mjcf(robot: RobotDescription, model: pin.Model | None = None, base_height: float = 0.7) -> str:
    """MJCF text of the robot on a flat floor.

    `model` replaces robot.model's inertias (scenarios with a payload or a link-mass
    change pass a modified copy of the nominal model); the kinematics are the same.
    """
    model = model if model is not None else robot.model
    children: dict[int, list[int]] = {}
    for j in range(2, model.njoints):
        children.setdefault(model.parents[j], []).append(j)
    feet_by_joint: dict[int, list[int]] = {}
    for fid in robot.foot_frame_ids:
        feet_by_joint.setdefault(model.frames[fid].parentJoint, []).append(fid)
    lower, upper = model.lowerPositionLimit, model.upperPositionLimit

    def body(j: int, indent: str) -> list[str]:
        M = model.jointPlacements[j]
        name = model.names[j]
        idx_q = model.joints[j].idx_q
        if not (np.isfinite(lower[idx_q]) and np.isfinite(upper[idx_q]) and lower[idx_q] < upper[idx_q]):
            raise MjcfError(f"joint {name}: needs finite position limits in the URDF")
        lines = [
            f'{indent}<body name="{name.removesuffix("_joint")}" pos="{_fmt(M.translation)}" '
            f'quat="{_fmt(_quat_wxyz(M.rotation))}">',
            f"{indent}  {_inertial(model.inertias[j])}",
            f'{indent}  <joint name="{name}" type="hinge" axis="{_fmt(_joint_axis(model.joints[j], name))}" '
            f'range="{lower[idx_q]:.17g} {upper[idx_q]:.17g}" limited="true"/>',
        ]
        # thin visual capsules from the joint to each child joint / foot (no collision, no mass)
        ends = [model.jointPlacements[c].translation for c in children.get(j, [])]
        ends += [model.frames[f].placement.translation for f in feet_by_joint.get(j, [])]
        for e in ends:
            if np.linalg.norm(e) > 1e-3:
                lines.append(f'{indent}  <geom type="capsule" fromto="0 0 0 {_fmt(e)}" size="0.02" '
                             f'contype="0" conaffinity="0" group="1" rgba="0.5 0.5 0.55 1"/>')
        for f in feet_by_joint.get(j, []):
            frame = model.frames[f]
            p = _fmt(frame.placement.translation)
            lines.append(f'{indent}  <site name="{frame.name}" pos="{p}" size="0.01"/>')
            lines.append(f'{indent}  <geom name="{frame.name}" type="sphere" size="{FOOT_RADIUS}" pos="{p}" '
                         f'friction="{FOOT_FRICTION} 0.005 0.0001" contype="1" conaffinity="1" condim="3" '
                         f'rgba="0.1 0.1 0.1 1"/>')
        for c in children.get(j, []):
            lines += body(c, indent + "  ")
        lines.append(f"{indent}</body>")
        return lines

    torso = [
        f'    <body name="base" pos="0 0 {base_height}">',
        f"      {_inertial(model.inertias[1])}",
        '      <freejoint name="root"/>',
        # collides with the floor only (contype 2 / floor conaffinity 3): a fallen robot lies on it
        '      <geom name="trunk" type="box" size="0.35 0.15 0.08" contype="2" conaffinity="0" '
        'rgba="0.7 0.3 0.2 1"/>',
    ]
    for c in children.get(1, []):
        torso += body(c, "      ")
    torso.append("    </body>")
    actuators = [f'    <motor name="{n}" joint="{n}" gear="1" ctrllimited="false" forcelimited="false"/>'
                 for n in robot.joint_names]
    return "\n".join([
        '<mujoco model="ciml_robot">',
        '  <compiler angle="radian" inertiafromgeom="false" balanceinertia="false" boundmass="0" '
        'boundinertia="0" autolimits="false"/>',
        f'  <option timestep="{TIMESTEP}" integrator="implicitfast" cone="elliptic" impratio="{IMPRATIO:g}" '
        'gravity="0 0 -9.81"/>',
        "  <default>",
        f'    <geom solref="{_fmt(CONTACT_SOLREF)}" solimp="{_fmt(CONTACT_SOLIMP)}"/>',
        '    <joint armature="0" damping="0" frictionloss="0" stiffness="0"/>',
        "  </default>",
        "  <worldbody>",
        '    <geom name="floor" type="plane" size="50 50 0.1" friction="1.0 0.005 0.0001" contype="1" '
        'conaffinity="3" rgba="0.8 0.8 0.8 1"/>',
        '    <light pos="0 0 3" dir="0 0 -1" directional="true"/>',
        *torso,
        "  </worldbody>",
        "  <actuator>",
        *actuators,
        "  </actuator>",
        "</mujoco>",
    ])


# --- state and force conventions (see the module docstring) -------------------------


def quat_xyzw_to_matrix(quat_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = quat_xyzw
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def pin_to_mj_velocity_map(q_pin: np.ndarray, nv: int) -> np.ndarray:
    """T (nv × nv) with qvel_mj = T v_pin: the base linear velocity rotated to the world frame."""
    T = np.eye(nv)
    T[:3, :3] = quat_xyzw_to_matrix(q_pin[3:7] / np.linalg.norm(q_pin[3:7]))
    return T


def pin_to_mj_state(q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    quat = np.asarray(q[3:7], dtype=float) / np.linalg.norm(q[3:7])
    R = quat_xyzw_to_matrix(quat)
    qpos = np.concatenate([q[:3], [quat[3], quat[0], quat[1], quat[2]], q[7:]])
    qvel = np.concatenate([R @ v[:3], v[3:]])
    return qpos, qvel


def mj_to_pin_state(qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    quat_xyzw = np.array([qpos[4], qpos[5], qpos[6], qpos[3]])
    quat_xyzw /= np.linalg.norm(quat_xyzw)
    R = quat_xyzw_to_matrix(quat_xyzw)
    q = np.concatenate([qpos[:3], quat_xyzw, qpos[7:]])
    v = np.concatenate([R.T @ qvel[:3], qvel[3:]])
    return q, v


def mj_to_pin_acceleration(q: np.ndarray, v: np.ndarray, qacc: np.ndarray) -> np.ndarray:
    """v̇_pin from MuJoCo's qacc: v̇_lin = Rᵀ p̈ − ω × v_lin (the base frame rotates)."""
    R = quat_xyzw_to_matrix(q[3:7])
    a = np.array(qacc, dtype=float)
    a[:3] = R.T @ qacc[:3] - np.cross(v[3:6], v[:3])
    return a


def pin_to_mj_acceleration(q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """qacc = T v̇ + Ṫ v (inverse of mj_to_pin_acceleration)."""
    R = quat_xyzw_to_matrix(q[3:7])
    qacc = np.array(a, dtype=float)
    qacc[:3] = R @ (a[:3] + np.cross(v[3:6], v[:3]))
    return qacc


def mj_to_pin_force(q: np.ndarray, f_mj: np.ndarray) -> np.ndarray:
    """Generalized force in Pinocchio coordinates: f_pin = Tᵀ f_mj."""
    out = np.array(f_mj, dtype=float)
    out[:3] = quat_xyzw_to_matrix(q[3:7]).T @ f_mj[:3]
    return out


def pin_to_mj_force(q: np.ndarray, f_pin: np.ndarray) -> np.ndarray:
    out = np.array(f_pin, dtype=float)
    out[:3] = quat_xyzw_to_matrix(q[3:7]) @ f_pin[:3]
    return out


def mj_mass_matrix_and_bias_in_pin(mj_model, mj_data, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's M and bias forces at the data's state, mapped to Pinocchio coordinates.

    M_pin = Tᵀ M_mj T and h_pin = Tᵀ (c_mj + M_mj Ṫ v); requires mj_forward (or mj_step)
    at the state (q, v) first.
    """
    import mujoco

    nv = mj_model.nv
    M = np.zeros((nv, nv))
    mujoco.mj_fullM(mj_model, mj_data, M)
    T = pin_to_mj_velocity_map(q, nv)
    Tdot_v = pin_to_mj_acceleration(q, v, np.zeros(nv))
    return T.T @ M @ T, mj_to_pin_force(q, mj_data.qfrc_bias + M @ Tdot_v)
