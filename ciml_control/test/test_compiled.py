"""The compiled kernels of the control step (ciml_control.compiled) against numpy."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from ciml_control.compiled.feedforward_qp import max_violation
from ciml_control.compiled.leg_ik import leg_newton_step
from ciml_control.compiled.linalg import min_norm_correction, qr_complete
from ciml_control.controller import IdController
from ciml_control.qp import contact_decomposition
from ciml_control.references import make_reference, standing_configuration
from ciml_learning.core.dynamics import RigidBodyDynamics
from ciml_learning.core.robot import load_robot


@pytest.fixture(scope="module")
def robot():
    return load_robot()


@pytest.mark.parametrize("shape", [(18, 12), (18, 6), (18, 9), (6, 6), (5, 1)])
def test_qr_complete_is_numpys_complete_qr(shape):
    rng = np.random.default_rng(shape[1])
    A = rng.standard_normal(shape)
    if shape[1] > 2:
        A[:, 2] = 0.0  # a zero column: a reflection-free step
    Q, R = qr_complete(A)
    Qn, Rn = np.linalg.qr(A, mode="complete")
    n = shape[1]
    np.testing.assert_allclose(Q, Qn, atol=1e-12)
    np.testing.assert_allclose(R, Rn[:n], atol=1e-12)
    np.testing.assert_allclose(Q.T @ Q, np.eye(shape[0]), atol=1e-13)
    np.testing.assert_allclose(Q[:, :n] @ R, A, atol=1e-12)


@pytest.mark.parametrize("contacts", [[1, 1, 1, 1], [1, 1, 1, 0], [1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 0, 0]])
def test_contact_decomposition_spans_the_right_spaces(robot, contacts):
    """J_cᵀ = Q_c R; Q_u ⟂ J_cᵀ; U_r: an orthonormal basis of the row space of Q_uᵀSᵀ."""
    rng = np.random.default_rng(3)
    q = pin.neutral(robot.model)
    q[7:] = robot.standing_joints + 0.2 * rng.standard_normal(robot.n_joints)
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(*(0.2 * rng.standard_normal(3)))).coeffs()
    J = RigidBodyDynamics(robot).foot_jacobians(q)
    c = np.asarray(contacts, bool)
    dec = contact_decomposition(J, c)
    Jc = J[c].reshape(-1, robot.nv)
    np.testing.assert_allclose(dec.Q_c @ dec.R, Jc.T, atol=1e-12)
    np.testing.assert_allclose(Jc @ dec.Q_u, 0.0, atol=1e-12)
    A = dec.Q_u[6:].T  # Q_uᵀSᵀ
    rank = np.linalg.matrix_rank(A)
    if dec.U_r is None:
        assert rank == A.shape[0]
    else:
        assert dec.U_r.shape == (A.shape[0], rank)
        np.testing.assert_allclose(dec.U_r.T @ dec.U_r, np.eye(rank), atol=1e-12)
        P = dec.U_r @ dec.U_r.T  # projector on the row space: leaves the columns of A unchanged
        np.testing.assert_allclose(P @ A, A, atol=1e-10)


def test_min_norm_correction_and_violation():
    rng = np.random.default_rng(0)
    A, b, x = rng.standard_normal((5, 12)), rng.standard_normal(5), rng.standard_normal(12)
    u = min_norm_correction(A, b, x)
    np.testing.assert_allclose(A @ u, b, atol=1e-12)
    np.testing.assert_allclose(u, x - np.linalg.pinv(A) @ (A @ x - b), atol=1e-12)
    C, l, c_u = rng.standard_normal((4, 12)), np.full(4, -1e20), np.full(4, 0.5)
    lb, ub = np.full(12, -1.0), np.full(12, 1.0)
    worst = max(np.abs(A @ x - b).max(), (C @ x - c_u).max(), (np.abs(x) - 1.0).max(), 0.0)
    assert max_violation(A, b, C, l, c_u, lb, ub, x) == pytest.approx(worst, abs=1e-12)
    x[3] = np.nan
    assert np.isnan(max_violation(A, b, C, l, c_u, lb, ub, x))


def test_leg_newton_step_converges_only_on_finite_small_errors(robot):
    cols = np.asarray([6 + np.asarray(leg) for leg in robot.leg_joints])  # velocity columns of each leg
    qidx = cols + 1                                                        # their configuration entries
    J = np.zeros((robot.n_feet, 3, robot.nv))
    for i, c in enumerate(cols):
        J[i][:, c] = np.eye(3)  # each foot moves with its own joints, identity blocks
    feet = np.zeros((robot.n_feet, 3))
    q = np.zeros(robot.nq)
    done, worst = leg_newton_step(J, feet, feet + 1e-13, q, qidx, cols, 1e-11, 1e-12, 0.5)
    assert done and worst == pytest.approx(1e-13) and not q.any()
    targets = feet + 0.1
    done, _ = leg_newton_step(J, feet, targets, q, qidx, cols, 1e-11, 1e-12, 0.5)
    assert not done and np.allclose(q[qidx], 0.1)  # one Newton step on an identity block
    targets[1, 2] = np.nan
    done, worst = leg_newton_step(J, feet, targets, q, qidx, cols, 1e-11, 1e-12, 0.5)
    assert not done and np.isnan(worst)


def test_desired_terms_are_reused_by_compute(robot):
    """ε from the controller's pass at the reference (desired_terms) then compute(): the same
    command as a controller that never shared its pass."""
    q_stand = standing_configuration(robot, 0.002)
    ref = make_reference(robot, "trot_35", q_stand)
    points = [ref.sample(1.0 + k / 250) for k in range(40)]
    shared, plain = IdController(robot), IdController(robot)
    rng = np.random.default_rng(1)
    for p in points:
        q = pin.integrate(robot.model, p.q, 0.003 * rng.standard_normal(robot.nv))
        v = p.v + 0.03 * rng.standard_normal(robot.nv)
        J = shared.desired_terms(p)[2].copy()
        np.testing.assert_array_equal(J, RigidBodyDynamics(robot).foot_jacobians(p.q))
        eps = np.zeros(robot.nv)
        eps[2] = J[0, 2, 2]  # any ε computed from the shared Jacobians
        a, b = shared.compute(q, v, p.contacts, p, eps), plain.compute(q, v, p.contacts, p, eps)
        np.testing.assert_allclose(a.feedforward, b.feedforward, atol=1e-9)
        np.testing.assert_allclose(a.feedback_linearization, b.feedback_linearization, atol=1e-9)
    # a changed reference point (same object, new values) is not served from the cache
    p = points[0]
    M0 = shared.desired_terms(p)[0].copy()
    p.q[7] += 0.1
    assert not np.array_equal(shared.desired_terms(p)[0], M0)
