"""Rigid-body dynamics quantities of the nominal model, all from Pinocchio.

Equation (3) of the paper: M(q) q̈ + h(q, q̇) + Φ̃ = Sᵀ τ + J_cᵀ λ_c.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ciml_learning.core.robot import RobotDescription


@dataclass
class DynamicsTerms:
    """Terms of eq. (3) at one state: M (nv×nv), h (nv), foot Jacobians (n_feet×3×nv)."""

    mass_matrix: np.ndarray
    nonlinear_effects: np.ndarray
    foot_jacobians: np.ndarray


def quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix.

    Through pin.SE3ToXYZQUAT: pin.Quaternion(matrix) leaks 76 bytes per call in the pin wheel
    used here (7.6 MB per 10⁵ calls, measured; from a 4-vector it does not), which grew a live
    reference generator's memory by 1.25 MB per simulated minute at 250 Hz."""
    return pin.SE3ToXYZQUAT(pin.SE3(np.asarray(rotation, dtype=float), np.zeros(3)))[3:]


def selection_matrix(robot: RobotDescription) -> np.ndarray:
    """S (n_j × nv) with S v = joint velocities; Sᵀ τ maps joint torques to generalized forces."""
    return np.hstack([np.zeros((robot.n_joints, 6)), np.eye(robot.n_joints)])


class RigidBodyDynamics:
    """Nominal dynamics of a robot description. Holds its own pinocchio.Data (not thread-safe)."""

    def __init__(self, robot: RobotDescription) -> None:
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q), symmetric (CRBA fills the upper triangle only)."""
        M = pin.crba(self.model, self.data, q)
        return np.triu(M) + np.triu(M, 1).T

    def nonlinear_effects(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """h(q, q̇): Coriolis, centrifugal and gravity generalized forces."""
        return pin.nonLinearEffects(self.model, self.data, q, v).copy()

    def inverse_dynamics(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """M(q) q̈ + h(q, q̇) by RNEA."""
        return pin.rnea(self.model, self.data, q, v, a).copy()

    def foot_positions(self, q: np.ndarray) -> np.ndarray:
        """World positions of the feet, (n_feet × 3) [m]."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return np.array([self.data.oMf[f].translation for f in self.robot.foot_frame_ids])

    def foot_jacobians(self, q: np.ndarray) -> np.ndarray:
        """Linear foot Jacobians in the world-aligned frame, (n_feet × 3 × nv)."""
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        return self._foot_jacobians()

    def _foot_jacobians(self) -> np.ndarray:
        return np.array(
            [
                pin.getFrameJacobian(self.model, self.data, f, pin.LOCAL_WORLD_ALIGNED)[:3]
                for f in self.robot.foot_frame_ids
            ]
        )

    def foot_velocities(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """World-aligned linear foot velocities, (n_feet × 3) [m/s]."""
        return np.einsum("fij,j->fi", self.foot_jacobians(q), v)

    def foot_acceleration_drift(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """J̇ q̇ of each foot's linear (classical) acceleration, (n_feet × 3) [m/s²]."""
        pin.forwardKinematics(self.model, self.data, q, v, np.zeros(self.model.nv))
        pin.updateFramePlacements(self.model, self.data)
        return np.array(
            [
                pin.getFrameClassicalAcceleration(self.model, self.data, f, pin.LOCAL_WORLD_ALIGNED).linear
                for f in self.robot.foot_frame_ids
            ]
        )

    def terms(self, q: np.ndarray, v: np.ndarray) -> DynamicsTerms:
        """M, h and the foot Jacobians at one state in one pass."""
        pin.computeAllTerms(self.model, self.data, q, v)
        pin.updateFramePlacements(self.model, self.data)
        M = self.data.M
        M = np.triu(M) + np.triu(M, 1).T
        return DynamicsTerms(M, self.data.nle.copy(), self._foot_jacobians())


@dataclass
class ReferenceState:
    """A reference point: time t [s], qᵈ (nq), q̇ᵈ, q̈ᵈ (nv), contact schedule (n_feet, bool)."""

    t: float
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    contacts: np.ndarray


class ReferenceTorque:
    """The joint torque τ_ref a reference asks for, and its rate τ̇_ref, for models of Γ(τ, τ̇).

    τ_ref = (Q_uᵀSᵀ)⁺ Q_uᵀ (M q̈ + h + e): the least-norm joint torques that realise the reference
    with its stance feet (Q_u spans null(J_cᵀ), so the contact forces drop out) — the controller's
    QP without friction cones and weights — clipped to the torque limits.

    τ̇_ref is the rate over the control period ahead, the one the command computed at t holds for
    (zero-order hold over [t, t + Δ]): the slope at t + Δ/2 of the parabola through the last three
    calls' τ_ref, from the past alone, (2τ(t) − 3τ(t − Δ) + τ(t − 2Δ))/Δ on a uniform grid (Δ the
    last step). A backward difference is the slope half a period in the past, and a lagging
    actuator's learned Γ(τ, τ̇) needs the one its command acts over (go1, headless: 2–9 % less
    feedback effort with the same models; results/live_online_learning/learning_order/).
    With only two calls of one contact schedule it is
    their difference; zero on the first call, after a time jump > 50 ms or backwards, and across
    a change of the contact schedule (where τ_ref jumps and a difference would be an impulse).
    Stateful: one instance per reference stream.
    """

    MAX_STEP = 0.05

    def __init__(self, robot: RobotDescription) -> None:
        self.robot = robot
        self._dyn = RigidBodyDynamics(robot)
        self._S = selection_matrix(robot)
        self._last: tuple[float, np.ndarray, np.ndarray] | None = None
        self._last_rate: tuple[float, np.ndarray] | None = None  # (Δ, backward difference) of the last call

    def torque(self, q: np.ndarray, v: np.ndarray, a: np.ndarray, contacts: np.ndarray,
               e: np.ndarray | None = None, foot_jacobians: np.ndarray | None = None) -> np.ndarray:
        """τ_ref (n_j) at one state, given the stance feet and a model error e (nv) to realise too
        (foot_jacobians at q: the caller's, if it has them)."""
        from ciml_learning.core.projection import contact_jacobian

        b = self._dyn.inverse_dynamics(q, v, a)
        if e is not None:
            b = b + e
        if foot_jacobians is None:
            foot_jacobians = self._dyn.foot_jacobians(q)
        Jc = contact_jacobian(foot_jacobians, contacts)
        if Jc.shape[0]:
            Q, _ = np.linalg.qr(Jc.T, mode="complete")
            Qu = Q[:, Jc.shape[0]:]
        else:
            Qu = np.eye(self.robot.nv)
        tau = np.linalg.lstsq(Qu.T @ self._S.T, Qu.T @ b, rcond=None)[0]
        return np.clip(tau, -self.robot.torque_limits, self.robot.torque_limits)

    def __call__(self, ref, e: np.ndarray | None = None,
                 foot_jacobians: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(τ_ref, τ̇_ref) at a ReferencePoint (ref.t, .q, .v, .a, .contacts; all feet down if absent)."""
        contacts = np.asarray(getattr(ref, "contacts", np.ones(self.robot.n_feet, bool)), bool)
        tau = self.torque(np.asarray(ref.q, float), np.asarray(ref.v, float), np.asarray(ref.a, float), contacts, e,
                          foot_jacobians)
        t = float(getattr(ref, "t", 0.0))
        tau_dot = np.zeros_like(tau)
        rate = None
        if self._last is not None:
            t1, tau1, contacts1 = self._last
            if 0 < t - t1 <= self.MAX_STEP and np.array_equal(contacts, contacts1):
                h = t - t1
                rate = (h, (tau - tau1) / h)
                tau_dot = rate[1]
                if self._last_rate is not None:
                    # Newton's form: p'(t + h/2) = d01 + 2h·d012, with d012 = (d01 − d12)/(t − t2)
                    h1, d12 = self._last_rate
                    tau_dot = rate[1] + 2.0 * h * (rate[1] - d12) / (h + h1)
        self._last = (t, tau, contacts)
        self._last_rate = rate
        return tau, tau_dot
