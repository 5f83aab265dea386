"""The inverse-dynamics controller of the paper (§IV): feedforward QP + feedback, 250 Hz.

    u = u_ff + u_fb,lin + K_p (qᵈ − q) + K_d (q̇ᵈ − q̇)          (the last two at 1 kHz)

- u_ff: `ciml_control.qp` at the desired state (qᵈ, q̇ᵈ, q̈ᵈ) and the reference contact
  schedule, with the model error ε of eq. (17) (zeros: nominal model), eq. (18–21).
- u_fb,lin: `ciml_control.feedback.feedback_linearization` at the measured state, eq. (24).
- PD targets and gains for the robot's 1 kHz joint loop.

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

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ciml_learning.dynamics import RigidBodyDynamics
from ciml_learning.errors import CimlError
from ciml_learning.robot import RobotDescription

from .feedback import FeedbackGains, feedback_linearization, tracking_error
from .qp import DEFAULT_F_MIN, DEFAULT_MU, FeedforwardQP, QPFailedError, build_feedforward_qp
from .references import ReferencePoint
from .standing import JointCommand, gravity_compensation


class ControllerInputError(CimlError):
    """The controller was given a state, reference or contact vector it cannot use."""


def _finite(x) -> bool:
    """All entries finite (fast path: one dot product is finite unless an entry is
    non-finite or huge; only then are the entries checked one by one)."""
    x = np.asarray(x, dtype=float)
    return math.isfinite(x @ x) or bool(np.isfinite(x).all())


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
            raise ControllerInputError(f"feedback_contacts must be 'reference' or 'measured', got {feedback_contacts!r}")
        self.robot = robot
        self.gains = gains or FeedbackGains.default(robot)
        self.gains.validate(robot)
        self.mu = mu
        self.f_min = f_min
        self.feedback_contacts = feedback_contacts
        self.limits = robot.torque_limits
        self._neg_limits = -self.limits
        self.dyn_des = RigidBodyDynamics(robot)
        self.dyn_meas = RigidBodyDynamics(robot)
        self._J = (np.zeros((robot.n_feet, 3, robot.nv)), np.zeros((robot.n_feet, 3, robot.nv)))  # des, meas
        self._M_des, self._h_des = np.zeros((robot.nv, robot.nv)), np.zeros(robot.nv)
        self._des_key: tuple | None = None
        self.qp = FeedforwardQP()
        self._zeros = np.zeros(robot.nv)  # ε of the nominal model (private, only read)
        self.qp_failures = 0
        self.epsilon_rejections = 0
        self.steps = 0

    def _terms(self, dyn: RigidBodyDynamics, q: np.ndarray, v: np.ndarray):
        """(M, h, foot Jacobians) in one Pinocchio pass (as dyn.terms, cheaper). M is
        Pinocchio's own buffer with only its upper triangle filled (CRBA), valid until the
        next pass on `dyn`; the kernels read the upper triangle only."""
        model, data = dyn.model, dyn.data
        pin.computeAllTerms(model, data, q, v)
        pin.updateFramePlacements(model, data)
        J = self._J[dyn is self.dyn_meas]
        for i, f in enumerate(self.robot.foot_frame_ids):
            J[i] = pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3]
        return data.M, data.nle, J

    def desired_terms(self, ref: ReferencePoint) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(M, h, foot Jacobians) of the nominal model at the reference (qᵈ, q̇ᵈ): one
        Pinocchio pass per reference point, shared with compute() — a model error ε that
        needs the contact Jacobians at qᵈ (the contact-invariant basis of eq. 17) can take
        them from here before compute(ref) without a second pass. M has only its upper
        triangle filled; the arrays are the controller's buffers (read them, do not keep
        them past the next call)."""
        q, v = np.asarray(ref.q, float), np.asarray(ref.v, float)
        key = (q.tobytes(), v.tobytes())
        if key != self._des_key:
            self._des_key = None
            M, h, _ = self._terms(self.dyn_des, q, v)
            np.copyto(self._M_des, M)  # private copies: other users of dyn_des cannot change them
            np.copyto(self._h_des, h)
            self._des_key = key
        return self._M_des, self._h_des, self._J[0]

    def _check(self, q, v, contacts, ref: ReferencePoint):
        r = self.robot
        q, v = np.asarray(q, float), np.asarray(v, float)
        contacts = np.asarray(contacts, dtype=bool)
        if q.shape != (r.nq,) or v.shape != (r.nv,) or contacts.shape != (r.n_feet,):
            raise ControllerInputError(
                f"state sizes q {q.shape}, v {v.shape}, contacts {contacts.shape}; expected ({r.nq},), ({r.nv},), ({r.n_feet},)")
        if not (_finite(q) and _finite(v)):
            raise ControllerInputError("non-finite measured state")
        if (np.shape(ref.q) != (r.nq,) or np.shape(ref.v) != (r.nv,) or np.shape(ref.a) != (r.nv,)
                or np.shape(ref.contacts) != (r.n_feet,)):
            raise ControllerInputError("reference sizes do not match the robot")
        if not (_finite(ref.q) and _finite(ref.v) and _finite(ref.a)):
            raise ControllerInputError("non-finite reference")
        return q, v, contacts

    def compute(self, q: np.ndarray, v: np.ndarray, contacts: np.ndarray, ref: ReferencePoint,
                epsilon: np.ndarray | None = None) -> ControlOutput:
        """One 250 Hz step: measured state (Pinocchio q, v), measured contacts, reference
        point, model error ε (nv, eq. 17; None or zeros = nominal model)."""
        t0 = time.perf_counter()
        q, v, contacts = self._check(q, v, contacts, ref)
        r = self.robot
        nv = r.nv
        ref_contacts = np.asarray(ref.contacts, dtype=bool)
        eps = self._zeros if epsilon is None else np.asarray(epsilon, float)
        eps_rejected = False
        if eps.shape != (nv,) or not _finite(eps):
            eps, eps_rejected = self._zeros, True
            self.epsilon_rejections += 1
        # feedforward QP at the desired state, eq. (18–21)
        M_des, h_des, J_des = self.desired_terms(ref)
        problem = build_feedforward_qp(M_des, h_des, J_des, ref_contacts, ref.a, eps, self.limits, self.mu, self.f_min)
        t1 = time.perf_counter()
        qp_failed, qp_error = False, ""
        forces = np.zeros((r.n_feet, 3))
        try:
            sol = self.qp.solve(problem)
            u_ff = sol.u
            forces[ref_contacts] = sol.contact_forces
        except QPFailedError as err:
            qp_failed, qp_error = True, str(err)
            self.qp_failures += 1
            u_ff = np.clip(gravity_compensation(self.dyn_des, ref.q, ref_contacts), -self.limits, self.limits)
        t2 = time.perf_counter()
        # feedback linearisation at the measured state, eq. (24)
        e, e_dot = tracking_error(r, q, v, ref.q, ref.v)
        fb_contacts = ref_contacts if self.feedback_contacts == "reference" else contacts
        M_meas, _, J_meas = self._terms(self.dyn_meas, q, v)
        u_lin = feedback_linearization(M_meas, J_meas, fb_contacts, e, e_dot, self.gains.kp_lin, self.gains.kd_lin)
        total = np.minimum(np.maximum(u_ff + u_lin, self._neg_limits), self.limits)  # np.clip, cheaper
        u_lin = total - u_ff
        if not (_finite(u_ff) and _finite(u_lin)):  # cannot happen with finite inputs
            raise ControllerInputError("controller produced a non-finite torque")
        self.steps += 1
        t3 = time.perf_counter()
        return ControlOutput(
            feedforward=u_ff, feedback_linearization=u_lin,
            q_target=np.asarray(ref.q[7:], float).copy(), qd_target=np.asarray(ref.v[6:], float).copy(),
            kp=self.gains.kp.copy(), kd=self.gains.kd.copy(), contact_forces=forces,
            qp_failed=qp_failed, epsilon_rejected=eps_rejected, unrealizable=problem.unrealizable,
            qp_error=qp_error, timings={"build_s": t1 - t0, "qp_s": t2 - t1, "feedback_s": t3 - t2})


def compute_benchmark(motion: str = "trot_35", n_steps: int = 2000, seed: int = 0, model_dir: str | None = None) -> dict:
    """p50/p99 of one control step as the id_controller node runs it: the model error ε at
    the reference (eq. 17: contact-invariant basis at qᵈ and a Φ̃', Γ prediction — from
    `model_dir` via ciml_learning.models.load_epsilon_function if given, else a fixed
    prediction) plus IdController.compute() (QP included), along a reference with a
    perturbed measured state. Reference samples are precomputed (the node receives them
    on /reference). Target p99 ≤ 1 ms (budget at 250 Hz: 4 ms)."""
    import pinocchio as pin

    from ciml_learning.dynamics import selection_matrix
    from ciml_learning.extraction import combined_error
    from ciml_learning.projection import contact_invariant_basis
    from ciml_learning.robot import load_robot

    from .references import make_reference, standing_configuration

    robot = load_robot()
    q_stand = standing_configuration(robot, 0.002)
    ref = make_reference(robot, motion, q_stand)
    rng = np.random.default_rng(seed)
    ts = 1.0 + np.arange(n_steps) / 250.0
    points = [ref.sample(t) for t in ts]
    ctrl = IdController(robot)
    S = selection_matrix(robot)
    phi = rng.normal(0.0, 5.0, len(robot.rbd_error_names))
    gamma = rng.normal(0.0, 2.0, robot.n_joints)
    if model_dir is not None:
        from ciml_learning.models import load_epsilon_function

        epsilon_fn = load_epsilon_function(robot, model_dir)
    else:
        def epsilon_fn(p):  # the contact Jacobians at qᵈ from the controller's pass at the reference
            basis = contact_invariant_basis(ctrl.desired_terms(p)[2], robot.leg_joints)
            return combined_error(basis, phi, gamma, S)
    for p in points[:50]:  # warm-up
        ctrl.compute(p.q, p.v, p.contacts, p, epsilon_fn(p))
    times, qp_times = [], []
    for p in points:
        q = pin.integrate(robot.model, p.q, 0.005 * rng.standard_normal(robot.nv))
        v = p.v + 0.05 * rng.standard_normal(robot.nv)
        t0 = time.perf_counter()
        out = ctrl.compute(q, v, p.contacts, p, epsilon_fn(p))
        times.append(time.perf_counter() - t0)
        qp_times.append(out.timings["qp_s"])
    t = np.array(times) * 1e6
    tq = np.array(qp_times) * 1e6
    return {"motion": motion, "steps": n_steps, "model": model_dir or "fixed prediction",
            "p50_us": round(float(np.percentile(t, 50)), 1), "p99_us": round(float(np.percentile(t, 99)), 1),
            "max_us": round(float(t.max()), 1),
            "qp_p50_us": round(float(np.percentile(tq, 50)), 1), "qp_p99_us": round(float(np.percentile(tq, 99)), 1),
            "qp_failures": ctrl.qp_failures, "target_p99_us": 1000.0}
