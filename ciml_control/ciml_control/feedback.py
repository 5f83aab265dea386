"""Feedback of the inverse-dynamics controller (paper eq. 22–24).

    u_fb = u_fb,pd + u_fb,lin
    u_fb,pd  = −K_d ė_j − K_p e_j                       joint PD, 1 kHz, next to the robot
    u_fb,lin = (P_c Sᵀ)⁺ P_c M (−K_d,lin ė − K_p,lin e)    feedback linearisation, 250 Hz

e = q ⊖ qᵈ (pin.difference(qᵈ, q): base part in the desired base frame), ė = v − vᵈ.
The linearisation term turns a desired correction of the full state's acceleration
(base included) into joint torques through the nominal mass matrix, with the contact
forces projected out (P_c = I − J_c⁺ J_c). With J_cᵀ = [Q_c Q_u][R; 0] one has
P_c = Q_u Q_uᵀ and (P_c Sᵀ)⁺ P_c = (Q_uᵀ Sᵀ)⁺ Q_uᵀ, which is what is computed.

The joint PD itself is not computed here: its targets (qᵈ, q̇ᵈ of the joints) and gains
go to the robot's 1 kHz joint loop in the TorqueCommand.

The gains (FeedbackGains) and CONTACT_RANK_TOL are the controller's. The specification of
eq. 24 is ciml_control.specification.feedback_linearization (literal pinv, tested equal to
the compiled step in test_specification); `feedback_linearization` here calls the compiled
kernel the product path runs (compiled.feedback_linearization.projected_pinv_apply, also
inside compiled.control_step), for tests and tools.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ciml_learning.core.robot import RobotDescription

from .compiled.feedback_linearization import projected_pinv_apply
from .compiled.linalg import arg

CONTACT_RANK_TOL = 1e-9
"""Relative eigenvalue tolerance of the rank test (as ciml_control.qp.contact_decomposition)."""

# joint loop gains tuned on HyQ (stance and swing legs alike); other robots get them scaled
# by joint_gain_scale (the robot's size)
JOINT_KP = 300.0   # [Nm/rad]
JOINT_KD = 8.0     # [Nm s/rad]
GAIN_REFERENCE_MASS = 86.774     # [kg] HyQ (example-robot-data), the robot JOINT_KP/KD were tuned on
# feedback linearisation gains, as accelerations per unit error [1/s², 1/s]
BASE_LINEAR_KP = 200.0
BASE_LINEAR_KD = 25.0
# Orientation twice as stiff as position (damping ratio kept, 0.88): in a trot two feet on a line
# cannot hold a moment about it, so roll is corrected only in the short four-foot phases. At
# 200 1/s² HyQ trotted leaning ±2.7° (two steady orbits, one each way; a few seconds of other
# commands moved it between them) and under a learned model the two orbits cost 37 and 23 Nm of
# feedback effort with the same ε; at 400 it trots at one lean (≤ 1.1°) with 30 % less effort,
# walk and base_only +4 % (results/LIVE_GRAPH.md, "Eighteenth session").
BASE_ANGULAR_KP = 400.0
BASE_ANGULAR_KD = 35.0
JOINT_LIN_KP = 0.0
JOINT_LIN_KD = 0.0


def joint_gain_scale(robot: RobotDescription) -> tuple[float, float]:
    """(stiffness scale, damping scale) of the joint loop gains for this robot's size.

    Both scale with the robot's mass relative to the robot the gains were tuned on
    (GAIN_REFERENCE_MASS), rounded to two significant digits (HyQ keeps exactly
    JOINT_KP/KD). Measured on go1 (13.1 kg → 0.15: 45 Nm/rad, 1.2 Nm s/rad), go1_gap
    scenario, trot_20, 8 s: RMS feedback effort 21.4 Nm with HyQ's gains (a chattering
    joint loop, torques at their limits) → 3.9 Nm, base position error 19.7 → 2.9 mm;
    scaling with mass × standing height (24 Nm/rad) tracked worse (6.0 Nm, 7.5 mm).
    """
    scale = float(f"{robot.total_mass / GAIN_REFERENCE_MASS:.2g}")
    return scale, scale


@dataclass
class FeedbackGains:
    """Gains of eq. (22–24): joint PD (n_j) and linearisation gains (nv)."""

    kp: np.ndarray
    kd: np.ndarray
    kp_lin: np.ndarray
    kd_lin: np.ndarray

    @classmethod
    def default(cls, robot: RobotDescription, kp: float | None = None, kd: float | None = None,
                base_kp: tuple[float, float] = (BASE_LINEAR_KP, BASE_ANGULAR_KP),
                base_kd: tuple[float, float] = (BASE_LINEAR_KD, BASE_ANGULAR_KD),
                joint_lin_kp: float = JOINT_LIN_KP, joint_lin_kd: float = JOINT_LIN_KD) -> "FeedbackGains":
        """Gains for `robot`; joint kp/kd default to JOINT_KP/KD scaled by joint_gain_scale."""
        nj = robot.n_joints
        if kp is None or kd is None:
            s_kp, s_kd = joint_gain_scale(robot)
            kp = JOINT_KP * s_kp if kp is None else kp
            kd = JOINT_KD * s_kd if kd is None else kd
        kp_lin = np.r_[np.full(3, base_kp[0]), np.full(3, base_kp[1]), np.full(nj, joint_lin_kp)]
        kd_lin = np.r_[np.full(3, base_kd[0]), np.full(3, base_kd[1]), np.full(nj, joint_lin_kd)]
        return cls(np.full(nj, kp), np.full(nj, kd), kp_lin, kd_lin)

    def validate(self, robot: RobotDescription) -> None:
        from ciml_learning.core.errors import CimlError

        for name, arr, n in (("kp", self.kp, robot.n_joints), ("kd", self.kd, robot.n_joints),
                             ("kp_lin", self.kp_lin, robot.nv), ("kd_lin", self.kd_lin, robot.nv)):
            a = np.asarray(arr, float)
            if a.shape != (n,) or not np.all(np.isfinite(a)) or np.any(a < 0):
                raise CimlError(f"feedback gain {name} must be {n} finite non-negative numbers")


def tracking_error(robot: RobotDescription, q: np.ndarray, v: np.ndarray, q_des: np.ndarray,
                   v_des: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e, ė) = (q ⊖ qᵈ, v − vᵈ), both nv."""
    return pin.difference(robot.model, q_des, q), v - v_des


def feedback_linearization(M: np.ndarray, foot_jacobians: np.ndarray, contacts: np.ndarray,
                           e: np.ndarray, e_dot: np.ndarray, kp_lin: np.ndarray, kd_lin: np.ndarray) -> np.ndarray:
    """u_fb,lin = (P_c Sᵀ)⁺ P_c M (−K_d ė − K_p e), eq. (24) [Nm] (n_j).

    Computed as (Q_uᵀ Sᵀ)⁺ Q_uᵀ M q̈_fb; where Q_uᵀ Sᵀ loses rank (two feet on a line) its
    zero rows are dropped first (ciml_control.qp.contact_decomposition), leaving a
    full-row-rank A with A⁺ = Aᵀ (A Aᵀ)⁻¹ (one compiled call:
    ciml_control.compiled.feedback_linearization.projected_pinv_apply). M: the mass matrix;
    only its upper triangle is read (as Pinocchio's CRBA fills it).
    """
    qdd_fb = -kd_lin * e_dot - kp_lin * e
    return projected_pinv_apply(arg(M), arg(foot_jacobians), arg(contacts, np.bool_), arg(qdd_fb),
                                        CONTACT_RANK_TOL)
