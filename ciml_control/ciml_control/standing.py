"""A standing controller: joint PD on a fixed posture plus gravity compensation with the
weight shared by the stance feet (least-norm contact forces of the static balance).

The bridge's standing hold; its gravity compensation is the controller's fallback when the QP
fails (the `stand` motion is a reference the controller tracks). Static balance,
eq. (3) with q̈ = 0, q̇ = 0: Sᵀu + J_cᵀλ = g(q). The base rows fix the contact forces
(least-norm solution), the joint rows then give u.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ciml_learning.core.dynamics import RigidBodyDynamics
from ciml_learning.core.projection import contact_jacobian
from ciml_learning.core.robot import RobotDescription

DEFAULT_KP = 300.0  # [Nm/rad] HyQ-like joint stiffness; other robots: scaled (feedback.joint_gain_scale)
DEFAULT_KD = 8.0    # [Nm s/rad]
SAFE_DAMPING = 10.0  # [Nm s/rad] joint damping of the safe (damping) mode on HyQ; other robots: safe_damping_gain


@dataclass
class JointCommand:
    """Everything a TorqueCommand carries, joint order of the robot."""

    feedforward: np.ndarray
    feedback_linearization: np.ndarray
    q_target: np.ndarray
    qd_target: np.ndarray
    kp: np.ndarray
    kd: np.ndarray


def gravity_compensation(dyn: RigidBodyDynamics, q: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """Joint torques that hold the robot still at q with the given stance feet [Nm]."""
    nv = dyn.robot.nv
    g = dyn.nonlinear_effects(q, np.zeros(nv))
    Jc = contact_jacobian(dyn.foot_jacobians(q), contacts)
    if Jc.shape[0] == 0:
        return g[6:].copy()
    lam = np.linalg.lstsq(Jc[:, :6].T, g[:6], rcond=None)[0]
    return g[6:] - Jc[:, 6:].T @ lam


def safe_damping_gain(robot: RobotDescription) -> float:
    """The damping mode's joint damping for `robot` [Nm s/rad]: SAFE_DAMPING scaled like the joint
    loop's damping (feedback.joint_gain_scale, by mass; HyQ 10, go1 1.5): HyQ's value on a small
    robot's light links is as much too stiff for the 1 kHz joint loop as HyQ's PD gains were."""
    from .feedback import joint_gain_scale

    return SAFE_DAMPING * joint_gain_scale(robot)[1]


class StandingController:
    def __init__(self, robot: RobotDescription, kp: float | None = None, kd: float | None = None) -> None:
        from .feedback import joint_gain_scale

        if kp is None or kd is None:
            s_kp, s_kd = joint_gain_scale(robot)
            kp = DEFAULT_KP * s_kp if kp is None else kp
            kd = DEFAULT_KD * s_kd if kd is None else kd
        self.robot = robot
        self.dyn = RigidBodyDynamics(robot)
        self.kp = np.full(robot.n_joints, kp)
        self.kd = np.full(robot.n_joints, kd)

    def compute(self, q_des: np.ndarray, contacts: np.ndarray) -> JointCommand:
        """Command that holds the configuration q_des (Pinocchio q) on the given stance feet."""
        limits = self.robot.torque_limits
        u = np.clip(gravity_compensation(self.dyn, q_des, contacts), -limits, limits)
        n = self.robot.n_joints
        return JointCommand(u, np.zeros(n), q_des[7:].copy(), np.zeros(n), self.kp.copy(), self.kd.copy())
