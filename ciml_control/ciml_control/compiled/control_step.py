"""One 250 Hz step of the controller, compiled (numba): named records in, torques out. The
nominal terms at the reference, the feedforward QP (feedforward_qp), the feedback linearisation
at the measured state (feedback_linearization); ciml_control.specification is the same step in
numpy, and IdController.compute its Python interface.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..native import DIFFERENCE, TERMS, ccall
from .feedback_linearization import clip_feedback, projected_pinv_apply
from .feedforward_qp import INFINITY, QP_SOLVED, feedforward_matrices, solve_feedforward
from .linalg import all_finite

STATE_NON_FINITE = 1
REFERENCE_NON_FINITE = 2
EPSILON_REJECTED = 4
"""Flags of `control_step`."""


@njit(cache=True)
def desired_terms(fns, dyn, q, v, key, M, h, J) -> None:
    """M, h, J of the core's model `dyn` at (q, v) into the buffers, skipped when key
    (q, v, valid flag) already holds this very (q, v)."""
    nq = q.shape[0]
    nv = v.shape[0]
    same = key[nq + nv] == 1.0
    if same:
        for i in range(nq):
            if key[i] != q[i]:
                same = False
                break
    if same:
        for i in range(nv):
            if key[nq + i] != v[i]:
                same = False
                break
    if same:
        return
    key[nq + nv] = 0.0
    ccall(fns[TERMS], (dyn, q.ctypes.data, v.ctypes.data, M.ctypes.data, h.ctypes.data, J.ctypes.data))
    key[:nq] = q
    key[nq:nq + nv] = v
    key[nq + nv] = 1.0


class ControlWorkspace(NamedTuple):
    """What the compiled control step keeps between steps (IdController builds it once; the
    arrays are updated in place): the C++ core's handles (ciml_control.native) and the
    buffers of the nominal terms at the reference (cached by `key`) and at the measured state."""

    functions: np.ndarray     # addresses of the core's C functions (native.function_table())
    dyn_des: int              # native.Dynamics handle for the terms at the reference (qᵈ, q̇ᵈ)
    dyn_meas: int             # native.Dynamics handle for the terms at the measured (q, v)
    qp: int                   # native.QpSolvers handle (one proxsuite solver per problem size)
    key: np.ndarray           # (qᵈ, q̇ᵈ, valid flag) the *_des buffers hold (desired_terms)
    M_des: np.ndarray         # nv × nv, upper triangle
    h_des: np.ndarray         # nv
    J_des: np.ndarray         # n_feet × 3 × nv
    M_meas: np.ndarray
    h_meas: np.ndarray
    J_meas: np.ndarray


class ControlParameters(NamedTuple):
    """The controller's constant parameters (IdController, fixed at construction)."""

    H: np.ndarray             # W_u of the QP cost ½uᵀW_u u (n_j × n_j; identity)
    g: np.ndarray             # linear cost (n_j; zeros)
    limits: np.ndarray        # torque limits (n_j) [Nm]
    cone: np.ndarray          # friction-cone rows of one foot (9 × 3, qp.friction_cone_matrix)
    f_min: float              # smallest normal force of a stance foot [N]
    rank_tol: float           # rank test of Q_uᵀSᵀ in the QP (qp.RANK_TOL)
    qp_tolerance: float       # largest accepted constraint violation, relative (FeedforwardQP.tolerance)
    kp_lin: np.ndarray        # feedback-linearisation gains (nv) [1/s²]
    kd_lin: np.ndarray        # (nv) [1/s]
    feedback_rank_tol: float  # rank test in eq. (24) (feedback.CONTACT_RANK_TOL)
    feedback_measured: bool   # P_c of eq. (24) from the measured contacts (else the reference's)


class ControlInput(NamedTuple):
    """One step's inputs: the measured state and contacts, the reference point, ε (eq. 17)."""

    q: np.ndarray             # measured configuration (Pinocchio, nq)
    v: np.ndarray             # measured velocity (nv)
    contacts: np.ndarray      # measured contacts (n_feet, bool)
    ref_q: np.ndarray         # qᵈ (nq)
    ref_v: np.ndarray         # q̇ᵈ (nv)
    ref_a: np.ndarray         # q̈ᵈ (nv)
    ref_contacts: np.ndarray  # the reference contact schedule (n_feet, bool)
    epsilon: np.ndarray       # model error ε (nv; zeros: nominal model)


class ControlOutputBuffers(NamedTuple):
    """Where the step writes its torques and planned forces."""

    u_ff: np.ndarray          # feedforward torque (n_j) [Nm]
    u_lin: np.ndarray         # feedback-linearisation torque (n_j) [Nm]
    forces: np.ndarray        # planned contact forces (n_feet × 3) [N], world frame, zero for swing feet


class StepResult(NamedTuple):
    """What `control_step` returns besides the output buffers."""

    flags: int                # STATE_NON_FINITE | REFERENCE_NON_FINITE | EPSILON_REJECTED
    status: int               # QP_SOLVED or the QP's failure (solve_feedforward)
    iterations: int           # proxsuite iterations
    unrealizable: float       # dropped part of eq. (19)'s right-hand side (qp.FeedforwardProblem)
    worst: float              # largest constraint violation of the QP answer


@njit(cache=True)
def control_step(work: ControlWorkspace, par: ControlParameters, inp: ControlInput,
                 out: ControlOutputBuffers) -> StepResult:
    """One step of ciml_control.controller.IdController.compute in one compiled call
    (work and par: IdController.workspace / .parameters; the same records the compiled
    closed loop, ciml_sim.joint_loop.closed_loop, passes):

    1. the nominal terms at the reference (qᵈ, q̇ᵈ) (cached by `work.key`, see desired_terms);
    2. the feedforward QP of eq. (18–21) with ε (zeros if ε is not finite), solved and
       checked (solve_feedforward) → out.u_ff and the planned contact forces out.forces;
    3. the feedback linearisation of eq. (24) at the measured state (the core's Pinocchio
       pass and difference) → out.u_lin, clipped with u_ff to the limits (clip_feedback)
       when the QP was solved; unclipped otherwise (the caller makes the fallback u_ff).

    Its specification is ciml_control.specification (the same equations in numpy,
    test_specification asserts the torques agree). With STATE_NON_FINITE or
    REFERENCE_NON_FINITE in the result's flags nothing else was computed."""
    fns, dyn_meas, limits = work.functions, work.dyn_meas, par.limits
    q, v, contacts, ref_q, ref_v, ref_a = inp.q, inp.v, inp.contacts, inp.ref_q, inp.ref_v, inp.ref_a
    ref_contacts, epsilon = inp.ref_contacts, inp.epsilon
    u_ff, u_lin, forces = out.u_ff, out.u_lin, out.forces
    if not (all_finite(q) and all_finite(v)):
        return StepResult(STATE_NON_FINITE, QP_SOLVED, 0, 0.0, 0.0)
    if not (all_finite(ref_q) and all_finite(ref_v) and all_finite(ref_a)):
        return StepResult(REFERENCE_NON_FINITE, QP_SOLVED, 0, 0.0, 0.0)
    flags = 0
    eps = epsilon
    if not all_finite(epsilon):
        flags |= EPSILON_REJECTED
        eps = np.zeros(epsilon.shape[0])
    nv = v.shape[0]
    desired_terms(fns, work.dyn_des, ref_q, ref_v, work.key, work.M_des, work.h_des, work.J_des)
    A, b, unrealizable, lam0, G, C, c_u, _, rhs = feedforward_matrices(
        work.M_des, work.h_des, work.J_des, ref_contacts, ref_a, eps, par.cone, par.f_min, par.rank_tol)
    lower = np.full(C.shape[0], -INFINITY)
    status, u, lam, iterations, worst = solve_feedforward(fns, work.qp, par.H, par.g, A, b, C, lower, c_u, -limits,
                                                          limits, lam0, G, rhs, par.qp_tolerance)
    forces[:] = 0.0
    u_ff[:] = 0.0
    if status == QP_SOLVED:
        u_ff[:] = u
        c = 0
        for f in range(forces.shape[0]):
            if ref_contacts[f]:
                for a in range(3):
                    forces[f, a] = lam[3 * c + a]
                c += 1
    # feedback linearisation at the measured state, eq. (24): q̈_fb = −K_d ė − K_p e
    e = np.empty(nv)
    ccall(fns[DIFFERENCE], (dyn_meas, ref_q.ctypes.data, q.ctypes.data, e.ctypes.data))
    qdd_fb = np.empty(nv)
    for i in range(nv):
        qdd_fb[i] = -par.kd_lin[i] * (v[i] - ref_v[i]) - par.kp_lin[i] * e[i]
    M_meas, J_meas = work.M_meas, work.J_meas
    ccall(fns[TERMS], (dyn_meas, q.ctypes.data, v.ctypes.data, M_meas.ctypes.data, work.h_meas.ctypes.data,
                      J_meas.ctypes.data))
    u_lin[:] = projected_pinv_apply(M_meas, J_meas, contacts if par.feedback_measured else ref_contacts, qdd_fb,
                                    par.feedback_rank_tol)
    if status == QP_SOLVED:
        clip_feedback(u_ff, u_lin, limits)
    return StepResult(flags, status, iterations, unrealizable, worst)


@njit(cache=True)
def control_step_arrays(functions, dyn_des, dyn_meas, qp, key, M_des, h_des, J_des, M_meas, h_meas, J_meas,
                        H, g, limits, cone, f_min, rank_tol, qp_tolerance, kp_lin, kd_lin, feedback_rank_tol,
                        feedback_measured, q, v, contacts, ref_q, ref_v, ref_a, ref_contacts, epsilon, u_ff, u_lin,
                        forces):
    """`control_step` called from Python (IdController.compute): the fields of its records
    ControlWorkspace, ControlParameters, ControlInput and ControlOutputBuffers as arguments,
    in that order and their field order (the caller passes *workspace, *parameters, …);
    returns StepResult's fields as a plain tuple.

    Why not the records themselves: numba types a named-tuple argument in Python on every
    call from Python, arrays in C — measured +5 µs on the ~120 µs step (ciml bench
    id_controller_step). Inside compiled code the records cost nothing, so compiled callers
    (ciml_sim.joint_loop.closed_loop) pass them."""
    r = control_step(
        ControlWorkspace(functions, dyn_des, dyn_meas, qp, key, M_des, h_des, J_des, M_meas, h_meas, J_meas),
        ControlParameters(H, g, limits, cone, f_min, rank_tol, qp_tolerance, kp_lin, kd_lin, feedback_rank_tol,
                          feedback_measured),
        ControlInput(q, v, contacts, ref_q, ref_v, ref_a, ref_contacts, epsilon),
        ControlOutputBuffers(u_ff, u_lin, forces))
    return r.flags, r.status, r.iterations, r.unrealizable, r.worst
