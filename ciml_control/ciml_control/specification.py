"""The controller of the paper (§IV, eq. 18–24) written out in numpy: the specification.

This module is what the compiled control step (ciml_control.compiled.control_step, with the
C++ core of ciml_control.native, called by ciml_control.controller.IdController and by the
headless closed loop ciml_sim.joint_loop.closed_loop) is tested against
(ciml_control/test/test_specification.py: the same torques on random states, references,
contact sets and model errors ε, including ε rejection and the QP fallback). Nothing on the
product path calls it: it favours the paper's notation over speed (Pinocchio's Python
bindings, numpy's QR / pinv / SVD, proxsuite on the QP over u with eq. 19 as equality
rows). Change the controller here first, then make the compiled path pass the test.

Feedforward, at the desired state (qᵈ, q̇ᵈ, q̈ᵈ) and the reference contact set, with ε (eq. 17):

    M q̈ᵈ + h + ε = Sᵀ u + J_cᵀ λ,            J_cᵀ = [Q_c Q_u] [R; 0]                (eq. 18)
    min_u ½ uᵀ W_u u    s.t.  Q_uᵀ Sᵀ u = Q_uᵀ (M q̈ᵈ + h + ε)                     (eq. 19)
                              λ = R⁻¹ Q_cᵀ (M q̈ᵈ + h + ε − Sᵀ u)                 (eq. 20)
                              F λ_f ≤ (0, …, 0, −f_min) per stance foot,  |u| ≤ τ_max  (eq. 21)

W_u = I, F the octagon friction cone (qp.friction_cone_matrix). Where Q_uᵀSᵀ loses rank (two
feet on a line, no feet), eq. 19 is kept on its row space (the part of the right-hand side
outside it no torque can produce; see ciml_control.qp). If the QP has no valid answer, the
feedforward is the static fallback: gravity compensation at qᵈ shared by the stance feet
(ciml_control.standing.gravity_compensation), clipped to τ_max. A non-finite ε is replaced
by zeros (the nominal model).

Feedback linearisation at the measured state (q, v) (eq. 22–24):

    e = q ⊖ qᵈ,  ė = v − q̇ᵈ,   u_fb,lin = (P_c Sᵀ)⁺ P_c M (−K_d ė − K_p e),   P_c = I − J_c⁺ J_c

with M, J_c at the measured state and the reference contact set (or the measured one,
feedback_contacts="measured"). The sum u_ff + u_fb,lin is clipped to τ_max, the clipping
taken from u_fb,lin. The joint PD of eq. 22 runs in the robot's 1 kHz loop (its law:
ciml_learning.core.conversions.commanded_torque).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import proxsuite

from ciml_learning.core.dynamics import RigidBodyDynamics
from ciml_learning.core.robot import RobotDescription

from .feedback import FeedbackGains
from .qp import DEFAULT_F_MIN, DEFAULT_MU, friction_cone_matrix
from .standing import gravity_compensation

RANK_RCOND = 1e-8
"""Singular values below this fraction of the largest count as zero (rank of Q_uᵀSᵀ, P_c Sᵀ)."""


@dataclass
class SpecificationOutput:
    u_ff: np.ndarray            # feedforward torque (n_j) [Nm]
    u_lin: np.ndarray           # feedback-linearisation torque (n_j) [Nm], after the clipping
    contact_forces: np.ndarray  # λ (n_feet × 3) [N], zero for swing feet and after a QP failure
    qp_solved: bool
    epsilon_rejected: bool


def nominal_terms(robot: RobotDescription, q: np.ndarray, v: np.ndarray):
    """(M, h, foot Jacobians (n_feet × 3 × nv, linear, LOCAL_WORLD_ALIGNED)) of the nominal model."""
    model, data = robot.model, robot.model.createData()
    pin.computeAllTerms(model, data, q, v)
    pin.updateFramePlacements(model, data)
    M = np.triu(data.M) + np.triu(data.M, 1).T
    J = np.array([pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3] for f in robot.foot_frame_ids])
    return M, data.nle.copy(), J


def selection(nv: int) -> np.ndarray:
    """S (n_j × nv): the actuated joints of the floating base."""
    return np.eye(nv)[6:]


def feedforward(M, h, J, contacts, qdd_des, epsilon, limits, mu=DEFAULT_MU, f_min=DEFAULT_F_MIN):
    """(u_ff, λ (n_contacts × 3)) of the QP of eq. 18–21, or None if it has no valid answer."""
    nv = M.shape[0]
    nj = nv - 6
    S = selection(nv)
    Jc = J[np.asarray(contacts, bool)].reshape(-1, nv)
    nc3 = Jc.shape[0]
    Q, R = np.linalg.qr(Jc.T, mode="complete")                       # eq. 18
    Q_c, Q_u, R = Q[:, :nc3], Q[:, nc3:], R[:nc3]
    rhs = M @ qdd_des + h + epsilon
    A, b = Q_u.T @ S.T, Q_u.T @ rhs                                   # eq. 19
    U, sv, _ = np.linalg.svd(A, full_matrices=False)
    keep = U[:, sv > RANK_RCOND * max(sv.max(initial=0.0), 1.0)]     # its row space
    A, b = keep.T @ A, keep.T @ b
    G = np.linalg.solve(R, Q_c.T @ S.T) if nc3 else np.zeros((0, nj))  # eq. 20: λ = lam0 − G u
    lam0 = np.linalg.solve(R, Q_c.T @ rhs) if nc3 else np.zeros(0)
    F = friction_cone_matrix(mu)                                      # eq. 21
    d = np.r_[np.zeros(len(F) - 1), -f_min]
    C = np.vstack([-F @ G[3 * i:3 * i + 3] for i in range(nc3 // 3)] or [np.zeros((0, nj))])
    c_u = np.concatenate([d - F @ lam0[3 * i:3 * i + 3] for i in range(nc3 // 3)] or [np.zeros(0)])
    qp = proxsuite.proxqp.dense.QP(nj, len(b), len(c_u), True)
    qp.settings.eps_abs, qp.settings.eps_rel, qp.settings.verbose = 1e-10, 0.0, False
    qp.settings.max_iter = 1000
    qp.init(np.eye(nj), np.zeros(nj), A, b, C, np.full(len(c_u), -1e20), c_u, -limits, limits)
    qp.solve()
    u = qp.results.x
    if qp.results.info.status != proxsuite.proxqp.QPSolverOutput.PROXQP_SOLVED or not np.all(np.isfinite(u)):
        return None
    scale = max(1.0, np.abs(b).max(initial=0.0), np.abs(c_u).max(initial=0.0))
    violation = max(np.abs(A @ u - b).max(initial=0.0), (C @ u - c_u).max(initial=0.0), (np.abs(u) - limits).max())
    if violation > 1e-6 * scale:
        return None
    return u, (lam0 - G @ u).reshape(-1, 3)


def feedback_linearization(M, J, contacts, e, e_dot, kp_lin, kd_lin) -> np.ndarray:
    """u_fb,lin = (P_c Sᵀ)⁺ P_c M (−K_d ė − K_p e), eq. 24."""
    nv = M.shape[0]
    Jc = J[np.asarray(contacts, bool)].reshape(-1, nv)
    P_c = np.eye(nv) - np.linalg.pinv(Jc, rcond=RANK_RCOND) @ Jc if len(Jc) else np.eye(nv)
    return np.linalg.pinv(P_c @ selection(nv).T, rcond=RANK_RCOND) @ P_c @ M @ (-kd_lin * e_dot - kp_lin * e)


def control_step(robot: RobotDescription, gains: FeedbackGains, q, v, contacts, ref_q, ref_v, ref_a, ref_contacts,
                 epsilon, mu: float = DEFAULT_MU, f_min: float = DEFAULT_F_MIN,
                 feedback_contacts: str = "reference") -> SpecificationOutput:
    """One control step (what IdController.compute computes): feedforward eq. 18–21 at the
    reference, feedback linearisation eq. 24 at the measured state, the clipping."""
    limits = np.asarray(robot.torque_limits, float)
    ref_contacts = np.asarray(ref_contacts, bool)
    rejected = not np.all(np.isfinite(epsilon))
    eps = np.zeros(robot.nv) if rejected else np.asarray(epsilon, float)
    M_d, h_d, J_d = nominal_terms(robot, ref_q, ref_v)
    solved = feedforward(M_d, h_d, J_d, ref_contacts, ref_a, eps, limits, mu, f_min)
    forces = np.zeros((robot.n_feet, 3))
    if solved is None:
        u_ff = np.clip(gravity_compensation(RigidBodyDynamics(robot), ref_q, ref_contacts), -limits, limits)
    else:
        u_ff, lam = solved
        forces[ref_contacts] = lam
    M, _, J = nominal_terms(robot, q, v)
    e, e_dot = pin.difference(robot.model, ref_q, q), v - ref_v
    fb_contacts = contacts if feedback_contacts == "measured" else ref_contacts
    u_lin = feedback_linearization(M, J, fb_contacts, e, e_dot, gains.kp_lin, gains.kd_lin)
    u_lin = np.clip(u_ff + u_lin, -limits, limits) - u_ff
    return SpecificationOutput(u_ff, u_lin, forces, solved is not None, rejected)
