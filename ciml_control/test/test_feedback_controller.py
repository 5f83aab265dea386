"""Feedback linearisation (eq. 24) and the IdController contract."""
import numpy as np
import pinocchio as pin
import pytest

from ciml_control.controller import ControllerInputError, IdController
from ciml_control.feedback import FeedbackGains, feedback_linearization, tracking_error
from ciml_control.references import ReferencePoint, make_reference
from ciml_control.standing import gravity_compensation
from ciml_learning.core.dynamics import RigidBodyDynamics, selection_matrix
from ciml_learning.core.errors import CimlError
from ciml_learning.core.projection import contact_jacobian, projector


def _random_state(robot, q_stand, seed):
    rng = np.random.default_rng(seed)
    q = pin.integrate(robot.model, q_stand, 0.1 * rng.standard_normal(robot.nv))
    return q, rng.standard_normal(robot.nv)


@pytest.mark.parametrize("contacts", [[1, 1, 1, 1], [1, 0, 1, 1], [0, 1, 1, 0], [0, 0, 0, 0]])
def test_feedback_linearization_matches_literal_formula(robot, q_stand, contacts):
    """(P_c Sᵀ)⁺ P_c M (−K_d ė − K_p e), computed literally with pinv, eq. (24)."""
    q, _ = _random_state(robot, q_stand, 3)
    rng = np.random.default_rng(4)
    e, edot = 0.05 * rng.standard_normal(robot.nv), 0.3 * rng.standard_normal(robot.nv)
    gains = FeedbackGains.default(robot, joint_lin_kp=40.0, joint_lin_kd=4.0)
    terms = RigidBodyDynamics(robot).terms(q, np.zeros(robot.nv))
    contacts = np.asarray(contacts, bool)
    u = feedback_linearization(terms.mass_matrix, terms.foot_jacobians, contacts, e, edot, gains.kp_lin, gains.kd_lin)
    assert np.all(np.isfinite(u))
    S = selection_matrix(robot)
    Pc = projector(contact_jacobian(terms.foot_jacobians, contacts))
    literal = np.linalg.pinv(Pc @ S.T, rcond=1e-8) @ Pc @ terms.mass_matrix @ (-gains.kd_lin * edot - gains.kp_lin * e)
    assert np.allclose(u, literal, atol=1e-8 * max(1.0, np.abs(literal).max()))
    assert np.allclose(feedback_linearization(terms.mass_matrix, terms.foot_jacobians, contacts, 0 * e, 0 * edot,
                                              gains.kp_lin, gains.kd_lin), 0.0)


def test_tracking_error_on_the_manifold(robot, q_stand):
    delta = np.linspace(-0.05, 0.05, robot.nv)
    q = pin.integrate(robot.model, q_stand, delta)
    e, edot = tracking_error(robot, q, np.ones(robot.nv), q_stand, np.zeros(robot.nv))
    assert np.allclose(e, delta, atol=1e-12) and np.allclose(edot, 1.0)


def test_feedback_opposes_base_height_error(robot, q_stand):
    """Base 2 cm too low with feet on the ground: the correction pushes the base up (more
    knee/hip torque against gravity, i.e. the linearised torque does positive work upward)."""
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    ctrl = IdController(robot)
    q = ref.q.copy()
    q[2] -= 0.02
    out = ctrl.compute(q, np.zeros(robot.nv), np.ones(4, bool), ref, np.zeros(robot.nv))
    terms = RigidBodyDynamics(robot).terms(q, np.zeros(robot.nv))
    S = selection_matrix(robot)
    Pc = projector(contact_jacobian(terms.foot_jacobians, np.ones(4, bool)))
    # generalized force of the correction, with contact forces projected out, has a positive base-z part
    gen = Pc @ (S.T @ out.feedback_linearization)
    up = Pc @ np.eye(robot.nv)[2]
    assert gen @ up > 0


def test_controller_at_reference_standing(robot, q_stand):
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    ctrl = IdController(robot)
    out = ctrl.compute(ref.q, ref.v, ref.contacts, ref, np.zeros(robot.nv))
    assert not out.qp_failed
    assert np.allclose(out.feedback_linearization, 0.0, atol=1e-9)
    mg = robot.total_mass * 9.81
    assert out.contact_forces[:, 2].sum() == pytest.approx(mg, rel=1e-3)
    assert np.allclose(out.q_target, ref.q[7:]) and np.allclose(out.qd_target, 0.0)
    assert out.kp.shape == (robot.n_joints,) and np.all(out.kp > 0) and np.all(out.kd > 0)
    assert np.all(np.abs(out.feedforward + out.feedback_linearization) <= robot.torque_limits)


def test_controller_along_trot_reference_has_no_qp_failure(robot, q_stand):
    ref = make_reference(robot, "trot_35", q_stand)
    ctrl = IdController(robot)
    for t in np.arange(0.0, 3.0, 0.02):
        p = ref.sample(t)
        out = ctrl.compute(p.q, p.v, p.contacts, p, np.zeros(robot.nv))
        assert not out.qp_failed, (t, out.qp_error)
        assert np.all(out.contact_forces[~p.contacts] == 0.0)
        assert np.all(out.contact_forces[p.contacts, 2] >= 5.0 - 1e-6)
    assert ctrl.qp_failures == 0


def test_outputs_respect_limits_under_large_errors(robot, q_stand):
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    ctrl = IdController(robot)
    q, v = _random_state(robot, q_stand, 7)
    q = pin.integrate(robot.model, q, np.full(robot.nv, 0.3))
    out = ctrl.compute(q, 20 * v, np.ones(4, bool), ref, np.zeros(robot.nv))
    total = out.feedforward + out.feedback_linearization
    assert np.all(np.isfinite(total))
    assert np.all(np.abs(total) <= robot.torque_limits + 1e-9)
    assert np.any(np.isclose(np.abs(total), robot.torque_limits))  # clipping was needed


def test_non_finite_state_raises_clear_error(robot, q_stand):
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    ctrl = IdController(robot)
    q = ref.q.copy()
    q[8] = np.nan
    with pytest.raises(ControllerInputError, match="non-finite"):
        ctrl.compute(q, ref.v, ref.contacts, ref, np.zeros(robot.nv))
    bad = ReferencePoint(0.0, ref.q, np.full(robot.nv, np.nan), ref.a, ref.contacts, 0.0, "stand")
    with pytest.raises(CimlError):
        ctrl.compute(ref.q, ref.v, ref.contacts, bad, np.zeros(robot.nv))
    with pytest.raises(ControllerInputError):
        ctrl.compute(ref.q[:-1], ref.v, ref.contacts, ref, np.zeros(robot.nv))


def test_non_finite_model_error_falls_back_to_nominal(robot, q_stand):
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    ctrl = IdController(robot)
    nominal = ctrl.compute(ref.q, ref.v, ref.contacts, ref, np.zeros(robot.nv))
    eps = np.zeros(robot.nv)
    eps[7] = np.nan
    out = ctrl.compute(ref.q, ref.v, ref.contacts, ref, eps)
    assert out.epsilon_rejected and ctrl.epsilon_rejections == 1
    assert np.allclose(out.feedforward, nominal.feedforward, atol=1e-6)


def test_model_error_enters_feedforward(robot, q_stand):
    """The feedforward satisfies the dynamics with ε: Sᵀ Δu + J_cᵀ Δλ = ε (eq. 17–19)."""
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    ctrl = IdController(robot)
    nominal = ctrl.compute(ref.q, ref.v, ref.contacts, ref, np.zeros(robot.nv))
    eps = np.zeros(robot.nv)
    eps[6:] = 3.0
    out = ctrl.compute(ref.q, ref.v, ref.contacts, ref, eps)
    eps[2] = 40.0
    out = ctrl.compute(ref.q, ref.v, ref.contacts, ref, eps)
    terms = RigidBodyDynamics(robot).terms(ref.q, ref.v)
    S = selection_matrix(robot)
    Jc = terms.foot_jacobians.reshape(-1, robot.nv)
    gen = S.T @ (out.feedforward - nominal.feedforward) + Jc.T @ (out.contact_forces - nominal.contact_forces).ravel()
    assert np.allclose(gen, eps, atol=1e-5)
    assert out.contact_forces[:, 2].sum() - nominal.contact_forces[:, 2].sum() == pytest.approx(40.0, rel=1e-6)


def test_qp_failure_falls_back_and_counts(robot, q_stand):
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    ctrl = IdController(robot, f_min=400.0)  # 4 × 400 N > m g: infeasible
    out = ctrl.compute(ref.q, ref.v, ref.contacts, ref, np.zeros(robot.nv))
    assert out.qp_failed and ctrl.qp_failures == 1 and out.qp_error
    static = np.clip(gravity_compensation(ctrl.dyn_des, ref.q, ref.contacts), -robot.torque_limits, robot.torque_limits)
    assert np.allclose(out.feedforward, static)
    assert np.all(np.isfinite(out.feedforward)) and np.all(out.contact_forces == 0.0)


def test_bad_gains_rejected(robot):
    gains = FeedbackGains.default(robot)
    gains.kp = -gains.kp
    with pytest.raises(CimlError):
        IdController(robot, gains=gains)
    with pytest.raises(CimlError):
        IdController(robot, feedback_contacts="guessed")
