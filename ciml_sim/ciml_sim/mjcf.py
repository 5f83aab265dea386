"""The MuJoCo model of the robot, generated from the Pinocchio model of its URDF.

Same kinematic tree, joint placements and axes, masses, CoMs and inertias (the
Pinocchio body inertias, which already merge fixed links), joint limits and torque
limits. Differences from the URDF model, all deliberate (see ciml_sim/README.md):
primitive geoms instead of .dae meshes (only foot spheres collide), soft contacts,
no URDF joint damping (the nominal model has none; friction is a scenario effect).

Free-joint conventions: MuJoCo qpos = [p, quat wxyz, joints], qvel = [linear velocity
in the world frame, angular velocity in the body frame, joints]; Pinocchio
q = [p, quat xyzw, joints], v = [linear and angular velocity in the body frame, joints].
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from ciml_learning.robot import RobotDescription

FOOT_RADIUS = 0.02
"""Foot sphere radius [m] (HyQ's feet are ~2 cm rubber balls)."""
FOOT_FRICTION = 1.0


def _fmt(values) -> str:
    return " ".join(f"{float(v):.12g}" for v in np.ravel(values))


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    c = pin.Quaternion(R).coeffs()  # x y z w
    return np.array([c[3], c[0], c[1], c[2]])


def _inertial(inertia: pin.Inertia) -> str:
    I = inertia.inertia
    full = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
    mass = max(inertia.mass, 1e-9)
    return f'<inertial pos="{_fmt(inertia.lever)}" mass="{mass:.12g}" fullinertia="{_fmt(full)}"/>'


def _joint_axis(jm) -> np.ndarray:
    name = jm.shortname()
    if name.endswith("RX"):
        return np.array([1.0, 0.0, 0.0])
    if name.endswith("RY"):
        return np.array([0.0, 1.0, 0.0])
    if name.endswith("RZ"):
        return np.array([0.0, 0.0, 1.0])
    if "RevoluteUnaligned" in name:
        return np.asarray(jm.axis, dtype=float)
    raise ValueError(f"unsupported joint type {name}")


def build_mjcf(robot: RobotDescription, model: pin.Model | None = None, base_height: float = 0.7) -> str:
    """MJCF text of the robot on a flat floor. `model` overrides robot.model's inertias
    (scenarios with payload or link-mass changes pass a modified copy)."""
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
        lines = [f'{indent}<body name="{name.removesuffix("_joint")}" pos="{_fmt(M.translation)}" quat="{_fmt(_quat_wxyz(M.rotation))}">',
                 f'{indent}  {_inertial(model.inertias[j])}',
                 f'{indent}  <joint name="{name}" type="hinge" axis="{_fmt(_joint_axis(model.joints[j]))}" '
                 f'range="{lower[idx_q]:.12g} {upper[idx_q]:.12g}" limited="true"/>']
        # a thin visual capsule from the joint to each child / foot (no collision, no mass)
        ends = [model.jointPlacements[c].translation for c in children.get(j, [])]
        ends += [model.frames[f].placement.translation for f in feet_by_joint.get(j, [])]
        for e in ends:
            if np.linalg.norm(e) > 1e-3:
                lines.append(f'{indent}  <geom type="capsule" fromto="0 0 0 {_fmt(e)}" size="0.02" '
                             f'contype="0" conaffinity="0" group="1" rgba="0.5 0.5 0.55 1"/>')
        for f in feet_by_joint.get(j, []):
            frame = model.frames[f]
            lines.append(f'{indent}  <site name="{frame.name}" pos="{_fmt(frame.placement.translation)}" size="0.005"/>')
            lines.append(f'{indent}  <geom name="{frame.name}" type="sphere" size="{FOOT_RADIUS}" '
                         f'pos="{_fmt(frame.placement.translation)}" friction="{FOOT_FRICTION} 0.005 0.0001" '
                         f'contype="1" conaffinity="1" condim="3" rgba="0.1 0.1 0.1 1"/>')
        for c in children.get(j, []):
            lines += body(c, indent + "  ")
        lines.append(f"{indent}</body>")
        return lines

    torso = [f'    <body name="base" pos="0 0 {base_height}">',
             f'      {_inertial(model.inertias[1])}',
             '      <freejoint name="root"/>',
             '      <geom type="box" size="0.35 0.15 0.08" contype="0" conaffinity="0" group="1" rgba="0.7 0.3 0.2 1"/>']
    for c in children.get(1, []):
        torso += body(c, "      ")
    torso.append("    </body>")
    actuators = [f'    <motor name="{n}" joint="{n}" forcerange="{-lim:.12g} {lim:.12g}" forcelimited="false"/>'
                 for n, lim in zip(robot.joint_names, robot.torque_limits)]
    return "\n".join([
        '<mujoco model="ciml_robot">',
        '  <compiler angle="radian" inertiafromgeom="false" balanceinertia="false" boundmass="0" boundinertia="0"/>',
        '  <option timestep="0.001" integrator="implicitfast" gravity="0 0 -9.81"/>',
        '  <default><geom solref="0.005 1" solimp="0.95 0.99 0.001"/></default>',
        "  <worldbody>",
        '    <geom name="floor" type="plane" size="50 50 0.1" friction="1.0 0.005 0.0001" contype="1" conaffinity="1"/>',
        *torso,
        "  </worldbody>",
        "  <actuator>",
        *actuators,
        "  </actuator>",
        "</mujoco>",
    ])


def pin_to_mj_velocity_map(q_pin: np.ndarray, nv: int) -> np.ndarray:
    """T with v_mj = T v_pin: the base linear velocity is rotated to the world frame."""
    T = np.eye(nv)
    T[:3, :3] = pin.Quaternion(q_pin[3:7]).matrix()
    return T


def pin_to_mj_state(q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    R = pin.Quaternion(q[3:7]).matrix()
    qpos = np.concatenate([q[:3], [q[6], q[3], q[4], q[5]], q[7:]])
    qvel = np.concatenate([R @ v[:3], v[3:]])
    return qpos, qvel


def mj_to_pin_state(qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    quat_xyzw = np.array([qpos[4], qpos[5], qpos[6], qpos[3]])
    quat_xyzw /= np.linalg.norm(quat_xyzw)
    R = pin.Quaternion(quat_xyzw).matrix()
    q = np.concatenate([qpos[:3], quat_xyzw, qpos[7:]])
    v = np.concatenate([R.T @ qvel[:3], qvel[3:]])
    return q, v


def mj_to_pin_acceleration(q: np.ndarray, v: np.ndarray, qacc: np.ndarray) -> np.ndarray:
    """v̇_pin from MuJoCo's qacc: a_mj = T a_pin + Ṫ v_pin, Ṫ v = [R (ω × v_lin), 0]."""
    R = pin.Quaternion(q[3:7]).matrix()
    a = qacc.copy()
    a[:3] = R.T @ qacc[:3] - np.cross(v[3:6], v[:3])
    return a


def mj_to_pin_force(q: np.ndarray, f_mj: np.ndarray) -> np.ndarray:
    """Generalized force in Pinocchio coordinates: τ_pin = Tᵀ τ_mj."""
    out = f_mj.copy()
    out[:3] = pin.Quaternion(q[3:7]).matrix().T @ f_mj[:3]
    return out


def pin_to_mj_force(q: np.ndarray, f_pin: np.ndarray) -> np.ndarray:
    out = np.array(f_pin, dtype=float)
    out[:3] = pin.Quaternion(q[3:7]).matrix() @ f_pin[:3]
    return out
