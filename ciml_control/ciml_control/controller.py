"""The inverse-dynamics controller of the paper (§IV): feedforward QP + feedback, 250 Hz.

    u = u_ff + u_fb,lin + K_p (qᵈ − q) + K_d (q̇ᵈ − q̇)          (the last two at 1 kHz)

- u_ff: `ciml_control.qp` at the desired state (qᵈ, q̇ᵈ, q̈ᵈ) and the reference contact
  schedule, with the model error ε of eq. (17) (zeros: nominal model), eq. (18–21).
- u_fb,lin: `ciml_control.feedback.feedback_linearization` at the measured state, eq. (24).
- PD targets and gains for the robot's 1 kHz joint loop.

The step runs compiled (ciml_control.compiled.control_step, its inputs and outputs named by the
records ControlWorkspace / ControlParameters / ControlInput / ControlOutputBuffers); its
specification is ciml_control.specification (eq. 18–24 in numpy, test_specification).

Safety (documented contract of `compute`):
- Non-finite q, v or reference → `ControllerInputError` (a CimlError); no output is made,
  the caller commands damping (the id_controller node does, and counts it).
- Non-finite ε → the nominal model is used for this step (`epsilon_rejected`).
- QP failure (infeasible, not converged, constraint violated) → no QP torque is used;
  the fallback feedforward is the static least-squares torque: gravity compensation
  at qᵈ with the weight shared by the reference stance feet (ciml_control.standing),
  clipped to the limits. `qp_failed` is set and `qp_failures` counted.
- u_ff + u_fb,lin is clipped to the URDF torque limits (the clipping is taken from the
  linearisation part); the joint loop clips the total again.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ciml_learning.core.dynamics import RigidBodyDynamics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription

from . import native
from .compiled.control_step import (
    EPSILON_REJECTED,
    REFERENCE_NON_FINITE,
    STATE_NON_FINITE,
    ControlParameters,
    ControlWorkspace,
    control_step_arrays,
    desired_terms,
)
from .compiled.feedback_linearization import clip_feedback
from .compiled.feedforward_qp import QP_SOLVED
from .compiled.linalg import all_finite, arg
from .feedback import CONTACT_RANK_TOL, FeedbackGains
from .qp import DEFAULT_F_MIN, DEFAULT_MU, RANK_TOL, FeedforwardQP, failure_message, friction_cone_matrix
from .references import ReferencePoint
from .standing import JointCommand, gravity_compensation


class ControllerInputError(CimlError):
    """The controller was given a state, reference or contact vector it cannot use."""


@dataclass
class ControlOutput(JointCommand):
    """One control step: the joint command (joint order of the robot) and how it was made.

    contact_forces: (n_feet × 3) planned contact forces of the QP [N] (world frame, zero for
    swing feet and after a QP failure).
    """

    contact_forces: np.ndarray
    qp_failed: bool
    epsilon_rejected: bool = False
    unrealizable: float = 0.0
    qp_error: str = ""
    timings: dict = field(default_factory=dict)


class IdController:
    """Inverse-dynamics QP controller with model-error feedforward (paper §IV).

    feedback_contacts: which contact set the feedback projector P_c uses — "reference"
    (the schedule the QP planned with) or "measured" (the contact sensors).
    """

    def __init__(self, robot: RobotDescription, gains: FeedbackGains | None = None, mu: float = DEFAULT_MU,
                 f_min: float = DEFAULT_F_MIN, feedback_contacts: str = "reference") -> None:
        if feedback_contacts not in ("reference", "measured"):
            raise ControllerInputError(
                f"feedback_contacts must be 'reference' or 'measured', got {feedback_contacts!r}")
        self.robot = robot
        self.gains = gains or FeedbackGains.default(robot)
        self.gains.validate(robot)
        self.mu = mu
        self.f_min = f_min
        self.feedback_contacts = feedback_contacts
        self.limits = np.ascontiguousarray(robot.torque_limits, dtype=float)
        self.dyn_des = RigidBodyDynamics(robot)  # the fallback torque after a QP failure
        self.qp = FeedforwardQP()
        # the compiled step's records (ControlWorkspace, ControlParameters): Pinocchio
        # models in the core, buffers, the cache key of the terms at the reference (qᵈ, q̇ᵈ, valid flag)
        self._core_des, self._core_meas = native.Dynamics(robot), native.Dynamics(robot)
        nv, nf = robot.nv, robot.n_feet
        self.workspace = ControlWorkspace(
            functions=native.function_table(), dyn_des=self._core_des.handle, dyn_meas=self._core_meas.handle,
            qp=self.qp._solvers.handle, key=np.zeros(robot.nq + nv + 1),
            M_des=np.zeros((nv, nv)), h_des=np.zeros(nv), J_des=np.zeros((nf, 3, nv)),
            M_meas=np.zeros((nv, nv)), h_meas=np.zeros(nv), J_meas=np.zeros((nf, 3, nv)))
        self._kp_lin = np.ascontiguousarray(self.gains.kp_lin, dtype=float)
        self._kd_lin = np.ascontiguousarray(self.gains.kd_lin, dtype=float)
        self.parameters = ControlParameters(
            H=np.eye(robot.n_joints), g=np.zeros(robot.n_joints), limits=self.limits,  # W_u = I
            cone=friction_cone_matrix(mu), f_min=float(f_min), rank_tol=RANK_TOL, qp_tolerance=self.qp.tolerance,
            kp_lin=self._kp_lin, kd_lin=self._kd_lin, feedback_rank_tol=CONTACT_RANK_TOL,
            feedback_measured=feedback_contacts == "measured")
        self._records = (*self.workspace, *self.parameters)
        self._zeros = np.zeros(nv)  # ε of the nominal model (private, only read)
        self.qp_failures = 0
        self.epsilon_rejections = 0
        self.steps = 0

    def desired_terms(self, ref: ReferencePoint) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(M, h, foot Jacobians) of the nominal model at the reference (qᵈ, q̇ᵈ): one
        Pinocchio pass per reference point, shared with compute() — a model error ε that
        needs the contact Jacobians at qᵈ (the contact-invariant basis of eq. 17) can take
        them from here before compute(ref) without a second pass. M has only its upper
        triangle filled; the arrays are the controller's buffers (read them, do not keep
        them past the next call)."""
        q, v = arg(ref.q), arg(ref.v)
        if q.shape != (self.robot.nq,) or v.shape != (self.robot.nv,):
            raise ControllerInputError("reference sizes do not match the robot")
        w = self.workspace
        desired_terms(w.functions, w.dyn_des, q, v, w.key, w.M_des, w.h_des, w.J_des)
        return w.M_des, w.h_des, w.J_des

    def _check(self, q, v, contacts, ref: ReferencePoint):
        """Sizes (finiteness is checked in the compiled step)."""
        r = self.robot
        q, v = arg(q), arg(v)
        contacts = arg(contacts, np.bool_)
        if q.shape != (r.nq,) or v.shape != (r.nv,) or contacts.shape != (r.n_feet,):
            raise ControllerInputError(
                f"state sizes q {q.shape}, v {v.shape}, contacts {contacts.shape}; "
                f"expected ({r.nq},), ({r.nv},), ({r.n_feet},)")
        ref_q, ref_v, ref_a = arg(ref.q), arg(ref.v), arg(ref.a)
        ref_contacts = arg(ref.contacts, np.bool_)
        if (ref_q.shape != (r.nq,) or ref_v.shape != (r.nv,) or ref_a.shape != (r.nv,)
                or ref_contacts.shape != (r.n_feet,)):
            raise ControllerInputError("reference sizes do not match the robot")
        return q, v, contacts, ref_q, ref_v, ref_a, ref_contacts

    def compute(self, q: np.ndarray, v: np.ndarray, contacts: np.ndarray, ref: ReferencePoint,
                epsilon: np.ndarray | None = None) -> ControlOutput:
        """One 250 Hz step: measured state (Pinocchio q, v), measured contacts, reference
        point, model error ε (nv, eq. 17; None or zeros = nominal model). The step itself
        is one compiled call (compiled.control_step: QP eq. 18–21, feedback eq. 24)."""
        t0 = time.perf_counter()
        q, v, contacts, ref_q, ref_v, ref_a, ref_contacts = self._check(q, v, contacts, ref)
        r = self.robot
        eps = self._zeros if epsilon is None else arg(epsilon)
        eps_rejected = eps.shape != (r.nv,)
        if eps_rejected:
            eps = self._zeros
        u_ff, u_lin, forces = np.empty(r.n_joints), np.empty(r.n_joints), np.empty((r.n_feet, 3))
        # the compiled step's records, field by field (control_step_arrays says why)
        flags, status, _, unrealizable, worst = control_step_arrays(
            *self._records, q, v, contacts, ref_q, ref_v, ref_a, ref_contacts, eps, u_ff, u_lin, forces)
        if flags & STATE_NON_FINITE:
            raise ControllerInputError("non-finite measured state")
        if flags & REFERENCE_NON_FINITE:
            raise ControllerInputError("non-finite reference")
        if eps_rejected or flags & EPSILON_REJECTED:
            eps_rejected = True
            self.epsilon_rejections += 1
        qp_failed, qp_error = status != QP_SOLVED, ""
        if qp_failed:
            qp_error = failure_message(status, worst, int(np.count_nonzero(ref_contacts)))
            self.qp_failures += 1
            u_ff = np.clip(gravity_compensation(self.dyn_des, ref_q, ref_contacts), -self.limits, self.limits)
            clip_feedback(u_ff, u_lin, self.limits)
        if not (all_finite(u_ff) and all_finite(u_lin)):  # not expected with finite inputs
            raise ControllerInputError("controller produced a non-finite torque")
        self.steps += 1
        return ControlOutput(
            feedforward=u_ff, feedback_linearization=u_lin, q_target=ref_q[7:].copy(), qd_target=ref_v[6:].copy(),
            kp=self.gains.kp.copy(), kd=self.gains.kd.copy(), contact_forces=forces,
            qp_failed=qp_failed, epsilon_rejected=eps_rejected, unrealizable=float(unrealizable),
            qp_error=qp_error, timings={"step_s": time.perf_counter() - t0})
